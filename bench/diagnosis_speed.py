"""How much time the model's geometry cache (wind_shaper.model.memo) saves a diagnosis.

    .venv/bin/python bench/diagnosis_speed.py            # 6 cases x 2 rounds; ~4 min on one core
    .venv/bin/python bench/diagnosis_speed.py --rounds 1

Each case is 12 simulated sweeps (seed as given) with hidden effects, diagnosed against the
commissioned reference once with the cache and once without, alternating within each round so
that both see the same machine load; the ratio is the median over rounds of (without / with).
Without the cache also means without the wall layer's own geometry cache, which it replaced.
The two diagnoses must agree to the last bit (summary text and final parameters), else the
bench stops. One BLAS thread (as in the test lane that runs the workbench tests). Writes
bench/out/diagnosis_speed.json and prints a Markdown table.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: (seed, hidden effects): library effects, held-out physics, and swirl (which rotates every
#: point by an angle that moves with the fit, so the cache can help least).
CASES = [(5, ('weak_fan',)), (103, ('jet_spreading',)), (104, ('jet_spreading', 'dead_band')),
         (5, ('plenum_starvation', 'wall_boundary_layer')), (5, ('jet_interaction',)),
         (5, ('wall_boundary_layer', 'swirl'))]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--rounds', type=int, default=2)
    ap.add_argument('--quick', action='store_true',
                    help='the first case only, on 6 sweeps, one round (seconds; for CI)')
    ap.add_argument('--out', '--json', dest='out',
                    default=str(ROOT / 'bench' / 'out' / 'diagnosis_speed.json'))
    args = ap.parse_args(argv)
    cases, n_sweeps = (CASES[:1], 6) if args.quick else (CASES, 12)
    if args.quick:
        args.rounds = 1
    from wind_shaper.app import Setup
    from wind_shaper.model import memo
    from wind_shaper.sim import make_effect
    from wind_shaper.workbench.commands import simulated_sweeps
    from wind_shaper.workbench.diagnose import Diagnosis

    setup = Setup.load()
    reference = setup.load_model(setup.config_dir / 'reference.yaml')
    rows = []
    for seed, effects in cases:
        sim = setup.make_sim(seed=seed, effects=[make_effect(e) for e in effects])
        data = simulated_sweeps(sim, n_sweeps, seed=seed)
        times = {'cache': [], 'none': []}
        results = {}
        for r in range(args.rounds):
            for arm in (('cache', 'none') if r % 2 == 0 else ('none', 'cache')):
                memo.clear()
                start = time.perf_counter()
                if arm == 'none':
                    with memo.switched_off():
                        d = Diagnosis().fit(reference, data, setup.geometry)
                else:
                    d = Diagnosis().fit(reference, data, setup.geometry)
                times[arm].append(time.perf_counter() - start)
                results[arm] = (d.summary(), d.final_.model.theta.tobytes())
        if results['cache'] != results['none']:
            print(f'seed {seed} {"+".join(effects)}: the diagnoses differ with and without the cache',
                  file=sys.stderr)
            return 1
        ratio = float(np.median(np.array(times['none']) / np.array(times['cache'])))
        row = {'seed': seed, 'effects': list(effects), 'seconds_cache': times['cache'],
               'seconds_none': times['none'], 'ratio': ratio,
               'named': [t.candidate.name for t in d.steps_]}
        rows.append(row)
        print(f'seed {seed} {"+".join(effects):40s} with {np.median(times["cache"]):5.1f} s, '
              f'without {np.median(times["none"]):5.1f} s: x{ratio:.2f}', flush=True)
    total_with = sum(np.median(r['seconds_cache']) for r in rows)
    total_without = sum(np.median(r['seconds_none']) for r in rows)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({'rounds': args.rounds, 'cases': rows,
                                          'total_seconds_cache': total_with,
                                          'total_seconds_none': total_without}, indent=1))
    print(f'\n| case ({n_sweeps} sweeps) | with cache [s] | without [s] | without / with |')
    print('|---|---|---|---|')
    for r in rows:
        print(f'| seed {r["seed"]}, {" + ".join(r["effects"])} | {np.median(r["seconds_cache"]):.1f} | '
              f'{np.median(r["seconds_none"]):.1f} | {r["ratio"]:.2f} |')
    print(f'| all | {total_with:.1f} | {total_without:.1f} | {total_without / total_with:.2f} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
