"""`wind-shaper collect`: run a designed experiment on the node graph (the coordinator's collect
service) and record it as a bag.

    wind-shaper collect --design lhs:12 --out commissioning      # 12 sweeps, fans off first and last
    wind-shaper collect --design single-off --out fan-check
    wind-shaper collect --design my_design.csv --out exp1 --duration 30
    wind-shaper collect --design lhs:12 --out x --dry-run        # show the design, move nothing

The design is made and checked here against the config (``--config``), then checked again by the
coordinator against its own; a bad design is refused whole before any fan moves. The sweeps are
stored in the coordinator's ``<run_root>/<out>/`` and, unless ``--no-bag``, recorded with the
raw streams into a bag (default ``bags/<out>``). Both are read by `wind-shaper model ... --data`
and `wind-shaper calibrate --data`. Calling again with the same design and name resumes: stored
sweeps are kept, flagged ones are swept again. If the coordinator dies during the experiment,
this command waits for it to come back (``--resume-wait``) and resumes. Ctrl-C cancels at the
next step; the fans go off.
"""
from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from pathlib import Path

from ..ros import names
from .service import STALE_STATUS_S, _not_running, _Session, _wait_arg

ROS2_EQUIVALENT = (f'ros2 service call /{names.COLLECT} wind_shaper_msgs/srv/Collect '
                   '"{name: exp1, fan_names: [...], commands: [...]}"')
RUNNING = ('commanding', 'sweeping', 'checking')
#: Topics the bag needs for `--data` (the rest are recorded when they have publishers).
BAG_NEEDS = (names.FORCE, names.PLATE_POSE, names.EXPERIMENT_SWEEPS)   # resolved when used


def _design(args):
    from ..app import Setup
    from ..experiment import make_design
    setup = Setup.load(args.config, args.disable)
    bounds = setup.shaping.bounds
    return setup, make_design(args.design, setup.geometry.fans, bounds.u_min, bounds.u_max,
                              seed=args.seed)


def format_design(design, enabled) -> str:
    head = f'{"":>3} {"label":<16}' + ''.join(f'{n:>7}' for n in design.fan_names)
    rows = [f'{i + 1:>3} {lab[:16]:<16}' + ''.join(f'{100 * u:7.1f}' for u in row)
            for i, (lab, row) in enumerate(zip(design.labels, design.commands))]
    return '\n'.join([f'design {design.source}: {len(design)} sweeps, commands in % of full PWM '
                      f'(spread {100 * design.spread(enabled):.0f} %)', head, *rows])


def _progress_line(s) -> str:
    bar_len = 20
    done = int(round(bar_len * min(max(s.progress, 0.0), 1.0)))
    row = f'sweep {s.sweep + 1}/{s.n_sweeps}' if s.sweep >= 0 else 'starting'
    again = f' (take {s.attempt})' if s.attempt > 1 else ''
    return (f'{row} {s.label[:14]:<14} {s.state:<10} [{"#" * done}{"-" * (bar_len - done)}] '
            f'{100 * s.progress:3.0f}%  coverage {100 * s.coverage:3.0f}%{again}  '
            f'stored {s.stored} flagged {s.flagged}')


def format_outcome(r) -> str:
    lines = []
    for i, (lab, out, cov) in enumerate(zip(r.labels, r.outcome, r.coverage)):
        cover = '-' if math.isnan(cov) else f'{100 * cov:.0f} %'
        lines.append(f'{i + 1:>3} {lab[:20]:<20} {out:<8} coverage {cover}')
    return '\n'.join(lines)


class _BagThread:
    """A Recorder of the sweep topics in its own rclpy context and thread."""

    def __init__(self, out: Path):
        import rclpy
        from rclpy.signals import SignalHandlerOptions

        from ..bag.recorder import Recorder
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        try:
            self.recorder = Recorder(out, context=self.context, node_name='wind_shaper_collect_bag')
        except BaseException:
            self.context.try_shutdown()
            raise
        self.stats = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        self.stats = self.recorder.record()

    def wait_subscribed(self, topics, timeout_s: float) -> list[str]:
        """Wait until ``topics`` are recorded; the ones still missing."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            missing = [t for t in topics if t not in self.recorder.subscribed]
            if not missing:
                return []
            time.sleep(0.1)
        return [t for t in topics if t not in self.recorder.subscribed]

    def close(self):
        self.recorder.stop()
        self.thread.join(10.0)
        self.context.try_shutdown()
        return self.stats


def _cmd_collect(args) -> int:
    setup, design = _design(args)
    enabled = setup.geometry.fans.enabled
    print(format_design(design, enabled), flush=True)
    if len(design) < 6:
        print(f'note: {len(design)} sweeps are enough to calibrate a prior; a diagnosis wants 8-12 '
              f'(try --design lhs:12)', flush=True)
    if args.dry_run:
        return 0
    from wind_shaper_msgs.msg import ExperimentStatus
    from wind_shaper_msgs.srv import Collect

    from ..ros import qos
    request = Collect.Request(name=args.out, design=design.source, fan_names=list(design.fan_names),
                              commands=[float(u) for u in design.commands.ravel()],
                              labels=list(design.labels), sweep_duration_s=args.duration,
                              timeout_s=args.timeout)
    tty = sys.stdout.isatty()
    bag = None
    with _Session() as session:
        client = session.node.create_client(Collect, names.COLLECT)
        if not session.wait_for_service(client, args.wait):
            return _not_running(names.COLLECT, args.wait)
        latest = [None, 0.0]

        def keep(msg):
            latest[0], latest[1] = msg, time.monotonic()

        session.node.create_subscription(ExperimentStatus, names.EXPERIMENT_STATUS, keep, qos.LATCHED)
        if not args.no_bag:
            bag_path = args.bag or Path('bags') / args.out
            if bag_path.exists():
                bag_path = bag_path.with_name(f'{bag_path.name}-{time.strftime("%Y%m%d-%H%M%S")}')
            bag = _BagThread(bag_path)
            missing = bag.wait_subscribed([names.resolve(t) for t in BAG_NEEDS], args.wait)
            if missing:
                print(f'warning: no publisher of {", ".join(missing)} yet; the bag may lack them',
                      file=sys.stderr)
        try:
            result = _call_with_resume(session, client, request, latest, args, tty)
        finally:
            if bag is not None:
                stats = bag.close()
                if stats is not None:
                    print(f'bag: {stats.path} ({stats.total} messages)')
        if result is None:
            return 2
        if result == 'interrupted':
            return 130
        print(format_outcome(result))
        print(result.message, file=sys.stdout if result.success else sys.stderr)
        if result.stored:
            where = f'{result.run_folder} (on the coordinator\'s machine)'
            print(f'next: wind-shaper model diagnose --data {where}'
                  + (f' or --data {bag.stats.path}' if bag is not None and bag.stats else ''))
        return 0 if result.success else 1


def _call_with_resume(session, client, request, latest, args, tty):
    """Call collect and show its feedback; when the coordinator goes silent (it died), wait for
    it to come back and call again (it resumes the experiment). Returns the response, None when
    no answer came, or 'interrupted' after a Ctrl-C (the experiment is then cancelled)."""
    resumes = 0
    while True:
        future = client.call_async(request)
        started, shown = time.monotonic(), ['']

        def show():
            s = latest[0]
            if s is None or s.name != request.name or s.state not in RUNNING:
                return
            line = _progress_line(s)
            if tty:
                print('\r' + line.ljust(100), end='', flush=True)
            elif (s.sweep, s.state, s.attempt) != shown[0]:
                print(line, flush=True)
                shown[0] = (s.sweep, s.state, s.attempt)

        def finished_or_gone():
            return future.done() or time.monotonic() - max(latest[1], started) > STALE_STATUS_S

        limit = args.timeout + 60.0 if args.timeout > 0 else 7 * 24 * 3600.0
        try:
            session.spin_until(finished_or_gone, limit, on_tick=show)
        except KeyboardInterrupt:
            session.interrupt(future.done, args.wait, tty, 30.0)
            return 'interrupted'
        if tty:
            print('\r' + ' ' * 100 + '\r', end='')
        if future.done():
            return future.result()
        client.remove_pending_request(future)
        if resumes >= args.max_resumes:
            print(f'no answer from the coordinator (no status for {STALE_STATUS_S:g} s) and '
                  f'{resumes} resume(s) already: check it, then run the same command again to resume',
                  file=sys.stderr)
            return None
        resumes += 1
        print(f'the coordinator went silent: waiting up to {args.resume_wait:g} s for it to come '
              f'back, then resuming the experiment ({resumes} of {args.max_resumes})', file=sys.stderr)
        if not session.wait_for_service(client, args.resume_wait):
            print(f'the coordinator did not come back within {args.resume_wait:g} s: restart it, '
                  f'then run the same command again to resume', file=sys.stderr)
            return None
        latest[1] = time.monotonic()


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'collect', help='run a designed experiment on the node graph: sweeps at given commands, '
                        'stored and recorded for `model ... --data` and `calibrate --data`',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=__doc__.split('\n\n')[0].rstrip('.') + '.',
        epilog=f'On a full ROS 2 install the call is:\n  {ROS2_EQUIVALENT}')
    p.add_argument('--design', required=True, metavar='SPEC',
                   help='lhs:N (N sweeps, fans off first and last, a Latin hypercube between) | '
                        'single-off (all at mid-range, then each fan off) | FILE.csv | FILE.yaml')
    p.add_argument('--out', required=True, metavar='NAME',
                   help='experiment name: its folder under the coordinator\'s run_root; the same '
                        'name and design again resumes it')
    p.add_argument('--config', type=Path, default=None,
                   help='config folder the design is checked against (default: the shipped one)')
    p.add_argument('--disable', action='append', default=[], metavar='FAN',
                   help='fan disabled in tunnel.yaml for this design (held at 0); repeat for more')
    p.add_argument('--seed', type=int, default=0, help='seed of an lhs design (default 0)')
    p.add_argument('--duration', type=float, default=0.0, metavar='S',
                   help='sweep duration [s] (default: the coordinator\'s sweep_duration_s)')
    p.add_argument('--timeout', type=float, default=0.0, metavar='S',
                   help='whole experiment timeout [s] (default: iteration_timeout_s per sweep)')
    p.add_argument('--bag', type=Path, default=None, help='bag to record (default: bags/NAME)')
    p.add_argument('--no-bag', action='store_true', help='record no bag (the folder still holds '
                                                         'every stored sweep)')
    p.add_argument('--dry-run', action='store_true', help='print the checked design and exit')
    p.add_argument('--resume-wait', type=float, default=60.0, metavar='S',
                   help='when the coordinator dies, wait this long for it to come back [s]')
    p.add_argument('--max-resumes', type=int, default=3, metavar='N',
                   help='resume at most N times after the coordinator died (default 3)')
    _wait_arg(p)
    p.set_defaults(func=_cmd_collect)


__all__ = ['register', 'format_design', 'format_outcome']
