"""Convergence benchmark: each method's true-field error relative to the best the fans can do.

For every case (target x fans disabled x hidden effects) the benchmark first finds zeta*, the
lowest true-field error [N^2] the fans can reach on the simulated tunnel, by optimising the
simulator's noise-free field directly over the bounded PWMs (scipy least_squares, trust-region
reflective, from U0 = 0.5 and several random starts; the best is kept). Then each method runs
the shaping loop on the noisy simulator (sweeps of 1000 samples, GP estimate) for every seed,
and every iteration is scored on the noise-free field at the key points.

Definitions (printed with the table):
  ratio_k      = MSE_true(U_k) / zeta*   (1.00 = the best reachable field)
  within 5 %   : MSE_true(U_k) <= 1.05 zeta*
  k to 5 %     : the first iteration k at which a run is within 5 %; median over seeds
                 ('-' if the median run never gets there)
  compute      : time of field estimation + update rule (the loop's work without the
                 simulated sweep and without the scoring), median per iteration [ms]: wall
                 clock and CPU time of the process's (single) compute thread
  peak memory  : tracemalloc peak of one run's estimation + update [MB]

Timing is only ever compared within one run of this script (the machine is shared); BLAS is
pinned to one thread (multithreaded BLAS on a busy 2-core machine has 100x outliers).

Usage: python bench/convergence.py [--seeds 5] [--iterations 12] [--quick] [--source static]
                                   [--zeta-cache FILE] [--json FILE]
The JSON goes to bench/out/convergence.json (--source plate) or bench/out/convergence_static.json
(--source static), with _quick before .json for a --quick run, unless --json names another file.
"""
from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from wind_shaper.app import Setup  # noqa: E402
from wind_shaper.control import ShapingLoop  # noqa: E402

TARGETS = ['uniform', 'gaussian@LM1', 'parabolic', 'expr:2.5 + 0.5*cos(3*theta)*r/0.3']
DISABLED = [(), ('CM',)]
EFFECTS = {'off': [], 'on': [{'name': 'weak_fan', 'fan': 'HM2', 'gain': 0.8},
                             {'name': 'swirl', 'gain': 0.5}]}
METHODS = {'paper': {'method': 'paper'}, 'adaptive': {'method': 'adaptive'}}
WITHIN = 1.05


def all_cases():
    return [(t, d, e) for e in EFFECTS for d in DISABLED for t in TARGETS]


def case_name(target, disabled, effects) -> str:
    short = 'user' if target.startswith('expr:') else target
    return f"{short}, off:{','.join(disabled) or '-'}, effects {effects}"


def make_sim(setup, seed, effects):
    from wind_shaper.sim import effects_from_config
    return setup.make_sim(seed=seed, effects=list(effects_from_config(EFFECTS[effects])))


def zeta_star(setup, target_values, effects, starts: int = 6, seed: int = 0):
    """The lowest true-field MSE [N^2] over the bounded PWMs, and its commands."""
    sim = make_sim(setup, 0, effects)
    kp = setup.geometry.key_points
    on = setup.geometry.fans.enabled
    lo, hi = setup.shaping.u_min, setup.shaping.u_max

    def residual(u):
        U = np.zeros(len(on))
        U[on] = u
        return sim.true_field(U, kp) - target_values

    rng = np.random.default_rng(seed)
    best = None
    for s in range(starts):
        u0 = np.full(on.sum(), np.clip(setup.shaping.u0, lo, hi)) if s == 0 else rng.uniform(lo, hi, on.sum())
        sol = least_squares(residual, u0, bounds=(lo, hi), diff_step=1e-4, xtol=1e-12, ftol=1e-12,
                            gtol=1e-12, max_nfev=400)
        z = float(np.mean(sol.fun ** 2))
        if best is None or z < best[0]:
            best = (z, sol.x)
    U = np.zeros(len(on))
    U[on] = best[1]
    return best[0], U


class _TimedTunnel:
    """Forwards to a tunnel and adds up the time spent in it (sweeps are not compute)."""

    def __init__(self, tunnel):
        self._t, self.geometry, self.seconds, self.cpu = tunnel, tunnel.geometry, 0.0, 0.0

    def _timed(self, fn, *args):
        t, c = time.perf_counter(), time.thread_time()
        try:
            return fn(*args)
        finally:
            self.seconds += time.perf_counter() - t
            self.cpu += time.thread_time() - c

    def apply(self, pwm):
        return self._timed(self._t.apply, pwm)

    def sweep(self, n_samples=1000):
        return self._timed(self._t.sweep, n_samples)

    def measure_at(self, positions, samples_per_point=20):
        return self._t.measure_at(positions, samples_per_point)


def run_method(setup, target_values, effects, rule_cfg, seed, iterations, memory=False, source='plate'):
    """One run: per-iteration true MSE, compute seconds per iteration, stop info, peak MB.
    source: 'plate' (the moving plate) or 'static' (``StaticSensorGrid`` over the same plant)."""
    sim = make_sim(setup, seed, effects)
    kp = setup.geometry.key_points
    if source == 'static':
        from wind_shaper.sim.static_grid import StaticSensorGrid
        tunnel = _TimedTunnel(StaticSensorGrid(sim))
    else:
        tunnel = _TimedTunnel(sim)
    rule = setup.shaping.make_rule(**rule_cfg)
    loop = ShapingLoop(tunnel, setup.load_model(), target_values, rule, setup.shaping.make_estimator(),
                       u0=setup.shaping.u0, n_samples=setup.shaping.samples_per_sweep)
    errors, compute, cpu, stops = [], [], [], []
    if memory:
        tracemalloc.start()
    for i in range(iterations + 1):
        s0, t0 = tunnel.seconds, time.perf_counter()
        c0 = (tunnel.cpu, time.thread_time())
        rec = loop.iterate(update=i < iterations)
        compute.append(time.perf_counter() - t0 - (tunnel.seconds - s0))
        cpu.append(time.thread_time() - c0[1] - (tunnel.cpu - c0[0]))
        if not memory:
            errors.append(float(np.mean((sim.true_field(rec.pwm, kp) - target_values) ** 2)))
        stops.append(bool(rec.info.get('stop', False)))
        bad = (rec.pwm < setup.shaping.u_min - 1e-12) | (rec.pwm > setup.shaping.u_max + 1e-12)
        assert not np.any(bad & setup.geometry.fans.enabled), 'a command left the bounds'
        assert np.all(rec.pwm[~setup.geometry.fans.enabled] == 0), 'a disabled fan was commanded'
    peak = None
    if memory:
        peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
        tracemalloc.stop()
    return np.array(errors), np.array(compute[:-1]), np.array(cpu[:-1]), stops, peak


def default_json(source: str, quick: bool = False) -> str:
    """The results file of a measurement source: each source keeps its own, and a --quick run
    never replaces the full results."""
    stem = 'convergence' if source == 'plate' else f'convergence_{source}'
    return f'bench/out/{stem}_quick.json' if quick else f'bench/out/{stem}.json'


def first_within(ratios) -> float:
    hit = np.flatnonzero(np.asarray(ratios) <= WITHIN)
    return float(hit[0]) if len(hit) else np.inf


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--seeds', type=int, default=5)
    ap.add_argument('--iterations', type=int, default=12)
    ap.add_argument('--json', default=None,
                    help='where to write the results (default: bench/out/convergence.json, or '
                         'bench/out/convergence_static.json with --source static; *_quick.json '
                         'with --quick)')
    ap.add_argument('--quick', action='store_true', help='effects off, no CM-off cases, 2 seeds')
    ap.add_argument('--source', choices=('plate', 'static'), default='plate',
                    help='measurement source: the moving plate (default) or the static sensor grid')
    ap.add_argument('--methods', default=','.join(METHODS))
    ap.add_argument('--zeta-cache', default=None,
                    help='JSON file to read/write zeta* per case (skips the optimisation when present)')
    ap.add_argument('--set', action='append', default=[],
                    help='override an adaptive setting, e.g. --set radius=0.5 (repeatable)')
    args = ap.parse_args(argv)
    if args.json is None:
        args.json = default_json(args.source, args.quick)
    methods = {m: dict(METHODS[m]) for m in args.methods.split(',')}
    for kv in args.set:
        key, _, value = kv.partition('=')
        methods['adaptive'][key] = json.loads(value) if value[:1] in '0123456789-[{tf' else value
    cases = all_cases()
    seeds = args.seeds
    if args.quick:
        cases = [c for c in cases if c[2] == 'off' and not c[1]]
        seeds = min(seeds, 2)
    rows = []
    zpath = Path(args.zeta_cache) if args.zeta_cache else None
    zcache = json.loads(zpath.read_text()) if zpath and zpath.is_file() else {}
    t_start = time.perf_counter()
    for target, disabled, effects in cases:
        setup = Setup.load(disabled=disabled)
        kp = setup.geometry.key_points
        tv = setup.make_target(target).values(kp)
        key = case_name(target, disabled, effects)
        if key in zcache:
            zs, U_star = zcache[key][0], np.array(zcache[key][1])
        else:
            zs, U_star = zeta_star(setup, tv, effects)
            zcache[key] = (zs, U_star.tolist())
        row = {'case': case_name(target, disabled, effects), 'target': target,
               'disabled': list(disabled), 'effects': EFFECTS[effects], 'zeta_star_N2': zs,
               'U_star': dict(zip(setup.geometry.fans.names, np.round(U_star, 4).tolist())),
               'methods': {}}
        for name, cfg in methods.items():
            runs, comp, cpu, stop_k = [], [], [], []
            for seed in range(seeds):
                err, c, cp, stops, _ = run_method(setup, tv, effects, cfg, seed, args.iterations,
                                                  source=args.source)
                runs.append(err / zs)
                comp.append(c)
                cpu.append(cp)
                stop_k.append(next((k for k, s in enumerate(stops) if s), None))
            _, _, _, _, peak = run_method(setup, tv, effects, cfg, 0, min(args.iterations, 4), memory=True,
                                          source=args.source)
            R = np.array(runs)
            hits = [first_within(r) for r in R]
            row['methods'][name] = {
                'median_ratio': np.median(R, 0).round(4).tolist(),
                'worst_ratio': R.max(0).round(4).tolist(),
                'k_within_5pct_median': float(np.median(hits)),
                'k_within_5pct_per_seed': hits,
                'compute_ms_median': float(1000 * np.median(np.concatenate(comp))),
                'compute_ms_max': float(1000 * np.max(np.concatenate(comp))),
                'compute_cpu_ms_median': float(1000 * np.median(np.concatenate(cpu))),
                'peak_memory_MB': peak,
                'stop_k_per_seed': stop_k,
                'ratio_per_seed': R.round(4).tolist(),
            }
        rows.append(row)
        print_row(row, methods)
    if zpath:
        zpath.parent.mkdir(parents=True, exist_ok=True)
        zpath.write_text(json.dumps(zcache, indent=1))
    print_table(rows, methods, seeds, args.iterations)
    print(f'\n({time.perf_counter() - t_start:.0f} s)')
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        meta = {'seeds': seeds, 'iterations': args.iterations, 'within': WITHIN, 'source': args.source,
                'methods': methods, 'definitions': __doc__}
        Path(args.json).write_text(json.dumps({'meta': meta, 'cases': rows}, indent=1, default=str))
        print(f'wrote {args.json}')


KS = (1, 2, 3, 4, 6, 12)


def _fmt_k(v):
    return '-' if not np.isfinite(v) else f'{v:.0f}'


def print_row(row, methods):
    parts = [f"{row['case']:38s} zeta*={row['zeta_star_N2']:.4f}"]
    for name in methods:
        m = row['methods'][name]
        r = m['median_ratio']
        parts.append(f"{name}: " + ' '.join(f'{r[k]:.3f}' for k in KS if k < len(r))
                     + f" k5%={_fmt_k(m['k_within_5pct_median'])}")
    print(' | '.join(parts), flush=True)


def print_table(rows, methods, seeds, iterations):
    ks = [k for k in KS if k <= iterations]
    print(f'\nTrue-field MSE / zeta* per iteration, median over {seeds} seeds (worst in brackets at k=4); '
          f'k5% = first iteration with MSE <= {WITHIN} zeta* (median over seeds)\n')
    head = ('| case | zeta* [N^2] | method | ' + ' | '.join(f'k={k}' for k in ks)
            + ' | k5% | ms/it (wall) | ms/it (cpu) | MB |')
    print(head)
    print('|' + '---|' * (head.count('|') - 1))
    for row in rows:
        for i, name in enumerate(methods):
            m = row['methods'][name]
            r, w = m['median_ratio'], m['worst_ratio']
            cells = [f'{r[k]:.3f}' + (f' ({w[k]:.2f})' if k == 4 else '') for k in ks]
            case = row['case'] if i == 0 else ''
            zs = f"{row['zeta_star_N2']:.4f}" if i == 0 else ''
            print(f"| {case} | {zs} | {name} | " + ' | '.join(cells)
                  + f" | {_fmt_k(m['k_within_5pct_median'])} | {m['compute_ms_median']:.1f} | "
                  + f"{m['compute_cpu_ms_median']:.1f} | {m['peak_memory_MB']:.1f} |")


if __name__ == '__main__':
    main()
