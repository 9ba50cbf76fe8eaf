"""`wind-shaper record` and `wind-shaper replay`: sweeps as rosbag2 bags (thin layer over
``wind_shaper.bag``; rclpy is imported only when one of them runs)."""
from __future__ import annotations

import signal
import time
from pathlib import Path


def _init_ros():
    """rclpy without its own signal handling: Ctrl-C / SIGTERM are handled by _stop_on_signals."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    return rclpy


def _stop_on_signals(worker) -> None:
    """The first Ctrl-C (SIGINT) or SIGTERM asks ``worker`` to stop (the recorder then closes
    its bag, so it stays readable); a second one interrupts at once."""
    def handler(signum, frame):
        if getattr(handler, 'fired', False):
            raise KeyboardInterrupt
        handler.fired = True
        worker.stop()
    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


def _cmd_record(args) -> int:
    from ..bag.recorder import Recorder
    from ..bag.topics import SWEEP_TOPICS, in_namespace
    from ..ros.names import namespace_from_env
    out = args.out or Path('bags') / time.strftime('sweeps-%Y%m%d-%H%M%S')
    topics = args.topics or [in_namespace(t, namespace_from_env()) for t in SWEEP_TOPICS]
    rclpy = _init_ros()
    try:
        recorder = Recorder(out, topics, storage=args.storage)
        _stop_on_signals(recorder)
        print(f'recording {len(topics)} topics into {out} '
              f'({"for %g s" % args.duration if args.duration else "until Ctrl-C"})', flush=True)
        stats = recorder.record(args.duration)
    finally:
        rclpy.try_shutdown()
    print(f'recorded {stats.total} messages in {stats.wall_s:.1f} s into {stats.path}')
    for topic, n in stats.counts.items():
        print(f'  {topic}: {n}')
    for topic in stats.missing:
        print(f'  {topic}: no publisher appeared')
    for topic, why in stats.skipped.items():
        print(f'  {topic}: skipped ({why})')
    return 0


def _cmd_replay(args) -> int:
    from ..bag.player import Player
    from ..bag.storage import bag_summary
    print(bag_summary(args.bag), flush=True)
    rclpy = _init_ros()
    player = None
    try:
        player = Player(args.bag, rate=args.rate, topics=args.topics, loop=args.loop,
                        restamp=args.restamp, wait_for_subscribers_s=args.wait_for_subscribers)
        _stop_on_signals(player)
        print(f'replaying {len(player.topics)} topics at rate {args.rate:g}'
              f'{" in a loop (Ctrl-C stops)" if args.loop else ""}', flush=True)
        stats = player.play()
    finally:
        if player is not None:
            player.destroy()
        rclpy.try_shutdown()
    print(f'published {stats.total} messages in {stats.passes} pass(es), {stats.wall_s:.2f} s '
          f'(behind schedule: median {1e3 * stats.late_percentile(50):.1f} ms, 90th percentile '
          f'{1e3 * stats.late_percentile(90):.1f} ms, latest {1e3 * stats.max_late_s:.1f} ms)')
    return 0


def _rate(text: str) -> float:
    import argparse
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'rate must be a number, got {text!r}') from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f'rate must be > 0 (1 = real time, 2 = twice as fast); got {text}')
    return value


def register(subparsers) -> None:
    p = subparsers.add_parser('record', help='record the sweep topics into a rosbag2 bag (MCAP)')
    p.add_argument('--out', type=Path, default=None,
                   help='bag folder to create (default: bags/sweeps-<time>); must not exist')
    p.add_argument('--topics', nargs='+', default=None, metavar='TOPIC',
                   help='topics to record (default: force, plate and mocap pose, fan command and '
                        'applied, field, iteration status)')
    p.add_argument('--duration', type=float, default=None, metavar='S',
                   help='stop after S seconds (default: until Ctrl-C)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap', help='bag storage format')
    p.set_defaults(func=_cmd_record)

    p = subparsers.add_parser('replay', help='publish a recorded bag again with its timing')
    p.add_argument('bag', type=Path, help='bag folder (holding metadata.yaml)')
    p.add_argument('--rate', type=_rate, default=1.0, help='speed factor (default 1: real time)')
    p.add_argument('--topics', nargs='+', default=None, metavar='TOPIC', help='topics to play (default: all)')
    p.add_argument('--loop', action='store_true', help='play again and again until Ctrl-C')
    p.add_argument('--restamp', action='store_true',
                   help='shift header stamps to the replay time (keeps their spacing)')
    p.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='S',
                   help='wait up to S seconds for a subscriber on every played topic before starting')
    p.set_defaults(func=_cmd_replay)

