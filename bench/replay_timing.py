"""How closely `wind-shaper replay` keeps a bag's timing: publish lateness and arrival error.

    .venv/bin/python bench/replay_timing.py            # rates 1 and 4, 3 replays each; ~30 s
    .venv/bin/python bench/replay_timing.py --quick    # one short replay at rate 4 (seconds)

A sweep bag (1.5 s of sweep: force 1 kHz, plate and mocap pose 100 Hz, commands, status; about
2.3 s in all) is replayed by the Player to a raw subscriber in the same process (events
executor in a thread). Printed per rate: the player's publish lateness behind its schedule
(median, 90th percentile, worst) and, at rate 1, each message's arrival time against its
recorded offset (median and 90th percentile of the absolute error, after removing the median
offset between the clocks). Faster than real time, the in-process subscriber (same GIL) is the
bottleneck, so arrival error is not reported there. Figures depend on the host's load: this is a
measurement, not a test.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--repeats', type=int, default=3)
    p.add_argument('--rates', type=float, nargs='+', default=[1.0, 4.0],
                   help='replay rates (1: real time)')
    p.add_argument('--samples', type=int, default=150, help='plate samples of the sweep (100 Hz)')
    p.add_argument('--quick', action='store_true',
                   help='one replay of a 0.3 s sweep at rate 4: checks the script runs')
    p.add_argument('--json', type=Path, default=None, help='also write the figures here')
    args = p.parse_args(argv)
    if args.quick:
        args.repeats, args.rates, args.samples = 1, [4.0], 30
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from wind_shaper.bag import BagReader, write_sweep_bag
    from wind_shaper.bag.player import Player, message_class
    from wind_shaper.core.geometry import TunnelGeometry
    from wind_shaper.sim import SimulatedTunnel

    geometry = TunnelGeometry.paper_rig()
    sim = SimulatedTunnel(geometry, seed=3, sample_rate_hz=100.0)
    sim.apply(np.full(geometry.fans.n_fans, 0.5))
    workdir = tempfile.TemporaryDirectory(prefix='replay_timing_')   # removed on return
    bag = write_sweep_bag(Path(workdir.name) / 'sweep', [sim.sweep(args.samples)], settle_s=0.2,
                          idle_streams=False)
    with BagReader(bag) as reader:
        topics = reader.topics
        recorded = list(reader.messages())
    t_bag = np.array([t for _, t, _ in recorded], dtype=float) * 1e-9
    context = rclpy.Context()
    rclpy.init(context=context)
    print('| rate | replays | publish late p50 [ms] | p90 [ms] | worst [ms] | arrival error p50 [ms] | p90 [ms] |')
    print('|---|---|---|---|---|---|---|')
    rows = []
    try:
        for rate in args.rates:
            late, err = [], []
            for _ in range(args.repeats):
                node = rclpy.create_node('replay_bench_listener', context=context)
                got = []
                deep = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
                for topic, info in topics.items():
                    node.create_subscription(message_class(info.msgtype), topic,
                                             (lambda t: lambda raw: got.append((t, time.monotonic())))(topic),
                                             deep, raw=True)
                executor = EventsExecutor(context=context)
                executor.add_node(node)
                stop = threading.Event()
                thread = threading.Thread(target=lambda: [executor.spin_once(timeout_sec=0.05)
                                                          for _ in iter(stop.is_set, True)], daemon=True)
                thread.start()
                player = Player(bag, rate=rate, context=context, wait_for_subscribers_s=10.0)
                try:
                    stats = player.play()
                    deadline = time.monotonic() + 10
                    while len(got) < len(recorded) and time.monotonic() < deadline:
                        time.sleep(0.01)
                finally:
                    player.destroy()
                    stop.set()
                    thread.join(5)
                    executor.shutdown()
                    node.destroy_node()
                late.extend(stats.late_s)
                if rate == 1.0 and len(got) == len(recorded):
                    per_topic = {t: iter([a for tt, a in got if tt == t]) for t in topics}
                    arrival = np.array([next(per_topic[t]) for t, _, _ in recorded])
                    lag = arrival - (t_bag - t_bag[0]) / rate
                    err.extend(np.abs(lag - np.median(lag)))
            late_ms = 1e3 * np.asarray(late)
            e = (f'{1e3 * np.median(err):.2f} | {1e3 * np.percentile(err, 90):.2f}' if err else '- | -')
            print(f'| {rate:g} | {args.repeats} | {np.median(late_ms):.1f} | {np.percentile(late_ms, 90):.1f} | '
                  f'{np.max(late_ms):.1f} | {e} |')
            rows.append({'rate': rate, 'replays': args.repeats,
                         'late_ms': {'p50': float(np.median(late_ms)),
                                     'p90': float(np.percentile(late_ms, 90)),
                                     'max': float(np.max(late_ms))},
                         'arrival_error_ms': ({'p50': 1e3 * float(np.median(err)),
                                               'p90': 1e3 * float(np.percentile(err, 90))}
                                              if err else None)})
    finally:
        context.try_shutdown()
        workdir.cleanup()
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({'samples': args.samples, 'rows': rows}, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
