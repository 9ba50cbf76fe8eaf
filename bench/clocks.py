"""How well the diagnosis tells forces and positions out of step (``workbench.sync.check_sync``):
false alarms on every simulated effect with the clocks in step, the lag measured when motion
capture runs late by 10-80 ms, and sweeps named when a clock steps during the experiment (three
of the twelve sweeps, the 5th to the 7th, with the positions 0.1-0.4 s late or early), over many
seeds.

    .venv/bin/python bench/clocks.py                 # 10 seeds, 12 sweeps; ~5 min on 2 cores

Data: ``simulated_sweeps`` (12 sweeps of 1000 samples at 50 Hz, first and last fans off) on the
default simulated tunnel; the model is the commissioned reference (config/reference.yaml), as the
diagnosis uses it. Writes bench/out/clocks.json and prints a Markdown table.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

LAGS_S = (0.01, 0.02, 0.04, 0.08)
#: a clock that steps during the experiment: these sweeps (0-based) with their positions moved
STEPPED_SWEEPS = (4, 5, 6)
STEPS_S = (0.1, 0.2, 0.4, -0.2)


def run_one(job) -> dict:
    effect, lag, seed, step = job
    from wind_shaper.app import Setup
    from wind_shaper.sim import MocapLatency, make_effect
    from wind_shaper.workbench.commands import simulated_sweeps
    from wind_shaper.workbench.sync import check_sync, repaired
    setup = Setup.load()
    reference = setup.load_model(setup.config_dir / 'reference.yaml')
    effects = ([make_effect(effect)] if effect else []) + ([MocapLatency(lag=lag)] if lag else [])
    data = simulated_sweeps(setup.make_sim(seed=seed, effects=effects), 12, seed=seed)
    if step:
        data = repaired(data, step, only=STEPPED_SWEEPS)
    check = check_sync(reference, data)
    return {'effect': effect or '(none)', 'lag_s': lag, 'step_s': step, 'seed': seed,
            'measured_s': round(check.lag_s, 5), 'out_of_step': check.out_of_step,
            'agree': round(check.agree, 3), 'mse_drop': round(check.drop, 4),
            'stepped': list(check.stepped)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--seeds', type=int, default=10)
    p.add_argument('--first-seed', type=int, default=100)
    p.add_argument('--jobs', type=int, default=2)
    p.add_argument('--quick', action='store_true',
                   help='one run of each kind: in step, 40 ms late, sweeps stepped 0.2 s (seconds)')
    p.add_argument('--json', type=Path, default=ROOT / 'bench' / 'out' / 'clocks.json')
    args = p.parse_args(argv)
    from wind_shaper.sim import HIDDEN_EFFECTS
    in_step = [''] + sorted(n for n in HIDDEN_EFFECTS if n not in ('mocap_latency', 'unequal_curves'))
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    if args.quick:
        jobs = [('', 0.0, args.first_seed, 0.0), ('', 0.04, args.first_seed, 0.0),
                ('', 0.0, args.first_seed, 0.2)]
    else:
        jobs = [(e, 0.0, s, 0.0) for e in in_step for s in seeds]
        jobs += [('', lag, s, 0.0) for lag in LAGS_S for s in seeds]
        jobs += [(e, 0.04, s, 0.0) for e in ('honeycomb_blockage', 'swirl', 'wall_reflection') for s in seeds]
        jobs += [('', 0.0, s, step) for step in STEPS_S for s in seeds]
        jobs += [(e, 0.0, s, 0.2) for e in ('honeycomb_blockage', 'swirl') for s in seeds]
    t0 = time.time()
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_one, jobs, chunksize=4))
    groups: dict = {}
    for r in rows:
        name = r['effect']
        if r['lag_s']:
            name += f" + {1000 * r['lag_s']:.0f} ms late"
        if r['step_s']:
            name += (f" + sweeps {', '.join(str(i + 1) for i in STEPPED_SWEEPS)} stepped "
                     f"{1000 * abs(r['step_s']):.0f} ms {'late' if r['step_s'] < 0 else 'early'}")
        groups.setdefault(name, []).append(r)
    want = list(STEPPED_SWEEPS)
    lines = ['| case | runs | said out of step | measured lag [ms], median (range) | stepped sweeps named: '
             'exactly / any |', '|---|---|---|---|---|']
    for name, rs in groups.items():
        got = sorted(1000 * r['measured_s'] for r in rs)
        exact = sum(r['stepped'] == want for r in rs)
        lines.append(f'| {name} | {len(rs)} | {sum(r["out_of_step"] for r in rs)}/{len(rs)} | '
                     f'{got[len(got) // 2]:+.1f} ({got[0]:+.1f} to {got[-1]:+.1f}) | '
                     f'{exact}/{len(rs)} / {sum(bool(r["stepped"]) for r in rs)}/{len(rs)} |')
    text = '\n'.join(lines)
    print(text)
    in_step_rows = [r for r in rows if r['lag_s'] == 0 and not r['step_s']]
    print(f'\nfalse alarms with the clocks in step: {sum(r["out_of_step"] for r in in_step_rows)}/'
          f'{len(in_step_rows)} out of step, {sum(bool(r["stepped"]) for r in in_step_rows)}/'
          f'{len(in_step_rows)} with a sweep named as stepped; {len(rows)} runs in {time.time() - t0:.0f} s')
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({'rows': rows, 'table': text}, indent=1))
    print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
