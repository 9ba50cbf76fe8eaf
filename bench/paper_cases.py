"""Per-iteration true-field error of the paper's Algorithm 1 on the simulated tunnel.

Prints a Markdown table (median over seeds of the true RMSE at the key points [N]) and writes
JSON. Usage: python bench/paper_cases.py [--seeds 5] [--iterations 12] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from wind_shaper.app import Setup, shape_on_sim

CASES = [('uniform', ()), ('gaussian@LM1', ()), ('parabolic', ()),
         ('uniform', ('CM',)), ('gaussian@LM1', ('CM',))]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--seeds', type=int, default=5)
    ap.add_argument('--iterations', type=int, default=12)
    ap.add_argument('--cases', type=int, default=len(CASES), help='the first N cases only')
    ap.add_argument('--json', default=None)
    args = ap.parse_args(argv)
    rows = []
    for target, disabled in CASES[:args.cases]:
        setup = Setup.load(disabled=disabled)
        runs, times = [], []
        for seed in range(args.seeds):
            t0 = time.perf_counter()
            records, _ = shape_on_sim(setup, target, iterations=args.iterations, seed=seed,
                                      rule_overrides={'method': 'paper'})
            times.append((time.perf_counter() - t0) / len(records))
            runs.append([np.sqrt(r.true_error) for r in records])
        runs = np.array(runs)
        final_pwm = records[-1].pwm
        rows.append({'target': target, 'disabled': list(disabled),
                     'median_true_rmse_N': np.median(runs, 0).round(4).tolist(),
                     'worst_true_rmse_N': runs.max(0).round(4).tolist(),
                     'mse_ratio_k6_k0': (float(np.median(runs[:, 6] ** 2 / runs[:, 0] ** 2))
                                         if runs.shape[1] > 6 else None),
                     'final_pwm_last_seed': dict(zip(setup.geometry.fans.names, final_pwm.round(3).tolist())),
                     'seconds_per_iteration': float(np.median(times))})
    ks = [0, 1, 2, 3, 4, 6, 8, 12]
    ks = [k for k in ks if k <= args.iterations]
    print(f'Median true RMSE [N] over {args.seeds} seeds (Algorithm 1, U0 = 0.5):\n')
    print('| target | fans off | ' + ' | '.join(f'k={k}' for k in ks) + ' | MSE(k6)/MSE(k0) |')
    print('|---|---|' + '---|' * len(ks) + '---|')
    for r in rows:
        vals = ' | '.join(f"{r['median_true_rmse_N'][k]:.3f}" for k in ks)
        k6 = '-' if r['mse_ratio_k6_k0'] is None else f"{r['mse_ratio_k6_k0']:.3f}"
        print(f"| {r['target']} | {','.join(r['disabled']) or '-'} | {vals} | {k6} |")
    print()
    for r in rows:
        pwm = ' '.join(f'{n}={100 * u:.0f}%' for n, u in r['final_pwm_last_seed'].items())
        print(f"{r['target']:13s} off={','.join(r['disabled']) or '-':3s} final PWM {pwm}; "
              f"{1000 * r['seconds_per_iteration']:.0f} ms/iteration (sim sweep + estimate + update)")
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(rows, fh, indent=1)


if __name__ == '__main__':
    main()
