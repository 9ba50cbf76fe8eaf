"""Where one iteration's time goes in the node graph: commanding, sweep, transfer, estimation,
update. Runs `wind-shaper up --sim --iterations N` (six processes, real MAVLink / Net F/T / ROS)
in a temporary folder and reads the coordinator's run folder. Prints a table; figures only.

Usage: python bench/iteration_split.py [--iterations 4] [--sweep 10] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

PHASES = [
    ('commanding', 'started', 'applied', 'fans commanded until the autopilot reports them applied'),
    ('settle + begin', 'applied', 'sweep_started', 'settling time and the begin_sweep call'),
    ('sweep', 'sweep_started', 'sweep_ended', 'plate motion (real time)'),
    ('transfer', None, None, 'estimate call minus the estimator\'s own compute: service round '
                             'trip with ~1000 pairs and 317-point field'),
    ('estimation', None, None, 'alignment + GET_CLOSEST + GP inside field_estimator'),
    ('update + record', 'estimated', 'finished', 'update rule and run-folder write'),
]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--iterations', type=int, default=4)
    ap.add_argument('--sweep', type=float, default=10.0, help='sweep duration [s]')
    ap.add_argument('--json', default=None)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, '-m', 'wind_shaper.cli.main', 'up', '--sim', '--iterations',
               str(args.iterations), '--target', 'parabolic', '--run-name', 'bench',
               '--set', f'coordinator.sweep_duration_s={args.sweep}']
        env = dict(os.environ)
        env.setdefault('ROS_DOMAIN_ID', str(os.getpid() % 100 + 1))
        done = subprocess.run(cmd, cwd=tmp, env=env, capture_output=True, text=True,
                              timeout=120 + args.iterations * (args.sweep + 60))
        if done.returncode != 0:
            print(done.stdout[-3000:], done.stderr[-3000:], sep='\n')
            print(f'wind-shaper up failed with exit code {done.returncode}', file=sys.stderr)
            return 1
        records = [json.loads(p.read_text()) for p in
                   sorted((Path(tmp) / 'runs' / 'bench' / 'iterations').glob('k*/record.json'))]
    rows = {name: [] for name, *_ in PHASES}
    for rec in records:
        t, info = rec['timestamps'], rec.get('info', {})
        compute = float(info.get('estimator_compute_s', float('nan')))
        for name, a, b, _ in PHASES:
            if a:
                rows[name].append(t[b] - t[a])
        rows['estimation'].append(compute)
        rows['transfer'].append(t['estimated'] - t['sweep_ended'] - compute)
    total = [r['timestamps']['finished'] - r['timestamps']['started'] for r in records]
    print(f'One iteration of the node graph on the simulated tunnel ({len(records)} iterations, '
          f'{args.sweep:g} s sweeps), median [ms]:\n')
    print('| phase | median [ms] | max [ms] | what |')
    print('|---|---|---|---|')
    summary = {}
    for name, _, _, what in PHASES:
        values = rows[name]
        summary[name] = {'median_ms': 1000 * statistics.median(values), 'max_ms': 1000 * max(values)}
        print(f'| {name} | {summary[name]["median_ms"]:.1f} | {summary[name]["max_ms"]:.1f} | {what} |')
    print(f'| total | {1000 * statistics.median(total):.1f} | {1000 * max(total):.1f} | |')
    if args.json:
        Path(args.json).write_text(json.dumps({'sweep_s': args.sweep, 'phases': summary,
                                               'total_ms': [1000 * x for x in total]}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
