"""Scale benchmark: the adaptive update on fan walls up to Caltech's 36 x 36 (1,296 fans).

Runs the shaping loop (default method: adaptive) on a simulated square fan wall and measures,
per iteration, the time of the field estimate and of the update rule (CPU time of the single
compute thread and wall time; the simulated sweep and the scoring are not counted), and the
peak memory of estimate + update (tracemalloc, i.e. what numpy and Python allocate) and of the
whole process (max RSS). The first iteration also builds the per-run caches (the prior's
sparse footprint basis and its Gram matrix); it is reported separately as "setup".

Wall: ``FanArray.grid(n, n, 0.08)`` (8 cm fans), key points on a square grid over the wall,
the simulated plant with the rig's jets, sweeps along the usual tour path over a disc that
covers the wall; prior: the rig's fitted jets (config/model.yaml) on every fan.

  python bench/scale.py                    # 36 x 36, 10,000 key points, 50,000 samples
  python bench/scale.py --series           # + how time grows with fans, key points, samples
                                           #   (writes bench/out/scale.json and docs/scaling.png)
  python bench/scale.py --gp-accuracy      # local GP vs exact GP on walls small enough for both
  python bench/scale.py --quick            # a 6 x 6 wall, 289 key points, 1,390 samples (seconds;
                                           #   writes bench/out/scale_quick.json)

Every run merges what it measured into the JSON (bench/out/scale.json): a --gp-accuracy run keeps
the --series data of an earlier run, so --replot still works.

(The GP-accuracy cases and the exact GP at 4,865 samples run in the same process and raise its
max RSS; run without --gp-accuracy for the wall's own footprint.)
"""
from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from wind_shaper.app import Setup  # noqa: E402
from wind_shaper.estimation.field import FieldEstimator, GaussianProcessField, LocalGaussianProcessField, closest_samples  # noqa: E402
from wind_shaper.core.geometry import FanArray, TunnelGeometry, rect_key_points  # noqa: E402
from wind_shaper.control import ShapingLoop  # noqa: E402
from wind_shaper.model import FanJets  # noqa: E402
from wind_shaper.sim import SimulatedTunnel  # noqa: E402

PITCH = 0.08


def wall(n_side: int, n_key: int, pitch: float = PITCH) -> TunnelGeometry:
    """An n x n fan wall with about n_key key points on a square grid over it."""
    fans = FanArray.grid(n_side, n_side, pitch)
    half = pitch * n_side / 2
    k = int(round(np.sqrt(n_key)))
    kp = rect_key_points(half, half, k, k)
    return TunnelGeometry(fans, kp, wall_radius=half + 0.1, sweep_radius=float(np.sqrt(2) * half) + 0.01,
                          extra={'wall_shape': 'square'})


def wall_prior(fans: FanArray) -> FanJets:
    """The rig's fitted jets (config/model.yaml) on every fan of the wall."""
    rig = Setup.load().load_model()
    jets = rig.k1 if hasattr(rig, 'k1') else rig
    return FanJets(fans, thrust_higher=jets.thrust_higher, thrust_lower=jets.thrust_lower, sigma=jets.sigma)


def run(n_side: int, n_key: int, n_samples: int, iterations: int = 4, target: float = 10.0,
        u0: float = 0.3, seed: int = 0, truth: bool = True, method: str = 'adaptive',
        memory: bool = False) -> dict:
    """One run on an n x n wall. Times are CPU/wall seconds of estimate and update per
    iteration; with ``memory`` tracemalloc records the peak (it slows allocation-heavy code
    several-fold, so timing runs leave it off)."""
    geo = wall(n_side, n_key)
    sim = SimulatedTunnel(geo, seed=seed)
    setup = Setup.load()
    rule = setup.shaping.make_rule(method=method)
    kp = geo.key_points
    tv = np.full(len(kp), target)
    loop = ShapingLoop(sim, wall_prior(geo.fans), tv, rule, FieldEstimator(), u0=u0, n_samples=n_samples)
    rows = []
    for i in range(iterations):
        applied = sim.apply(loop.U)
        sweep = sim.sweep(n_samples)
        # the loop's own work, split: estimate, then update (the sweep above is not timed)
        rows_est = {}

        def measure(applied=applied, sweep=sweep, rows_est=rows_est):
            # ShapingLoop.measure's (applied, sweep, estimate, region): a whole sweep, no region
            return applied, sweep, _timed(rows_est, loop.estimator.estimate, sweep, kp), {}
        loop.measure = measure
        if memory:
            tracemalloc.start()
        c0, w0 = time.thread_time(), time.perf_counter()
        rec = loop.iterate(update=True)
        cpu, wall_s = time.thread_time() - c0, time.perf_counter() - w0
        peak = None
        if memory:
            peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
            tracemalloc.stop()
        row = {'k': i, 'estimate_cpu_s': rows_est['cpu'], 'estimate_wall_s': rows_est['wall'],
               'update_cpu_s': cpu - rows_est['cpu'], 'update_wall_s': wall_s - rows_est['wall'],
               'peak_traced_MB': peak, 'max_rss_MB': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
               'est_rmse_N': float(np.sqrt(rec.error)), 'mode': rec.info.get('mode')}
        if truth:
            row['true_rmse_N'] = float(np.sqrt(np.mean((sim.true_field(rec.pwm, kp) - tv) ** 2)))
        rows.append(row)
        print(f"  {n_side}x{n_side} fans, {len(kp)} key points, {n_samples} samples, k={i}: estimate "
              f"{row['estimate_cpu_s']:.2f} s, update {row['update_cpu_s']:.2f} s (cpu); "
              + (f"peak {peak:.0f} MB traced, " if memory else '') + f"{row['max_rss_MB']:.0f} MB rss"
              + (f"; true RMSE {row['true_rmse_N']:.3f} N" if truth else ''), flush=True)
    if truth:  # the commands of the last update, measured
        row = {'k': iterations, 'true_rmse_N': float(np.sqrt(np.mean((sim.true_field(loop.U, kp) - tv) ** 2)))}
        rows.append(row)
    steady = rows[1:iterations]
    return {'fans': n_side * n_side, 'key_points': len(kp), 'samples': n_samples, 'iterations': rows,
            'setup_cpu_s': rows[0]['update_cpu_s'] - float(np.median([r['update_cpu_s'] for r in steady])),
            'estimate_cpu_s': float(np.median([r['estimate_cpu_s'] for r in steady])),
            'update_cpu_s': float(np.median([r['update_cpu_s'] for r in steady])),
            'total_cpu_s': float(np.median([r['estimate_cpu_s'] + r['update_cpu_s'] for r in steady])),
            'total_wall_s': float(np.median([r['estimate_wall_s'] + r['update_wall_s'] for r in steady])),
            'peak_traced_MB': (float(max(r['peak_traced_MB'] for r in rows[:iterations])) if memory else None),
            'max_rss_MB': float(rows[iterations - 1]['max_rss_MB'])}


def _timed(out, fn, *args):
    c, w = time.thread_time(), time.perf_counter()
    try:
        return fn(*args)
    finally:
        out['cpu'], out['wall'] = time.thread_time() - c, time.perf_counter() - w


def gp_accuracy(cases=((6, 1200, 6000), (12, 2500, 12500), (12, 4900, 25000)), seed=0) -> list:
    """Local GP (the large-wall estimator) against the exact GP on the same GET_CLOSEST samples."""
    out = []
    for n_side, n_key, n_samples in cases:
        geo = wall(n_side, n_key)
        sim = SimulatedTunnel(geo, seed=seed)
        sim.apply(np.full(geo.fans.n_fans, 0.3))
        sub = closest_samples(sim.sweep(n_samples).finite(), geo.key_points)
        est = FieldEstimator()
        kp = geo.key_points
        c = time.thread_time()
        me, se = GaussianProcessField(est.length_scale, est.noise_std).fit(sub.positions, sub.forces).predict(kp, True)
        t_exact = time.thread_time() - c
        c = time.thread_time()
        ml, sl = LocalGaussianProcessField(est.length_scale, est.noise_std, block=est.local_block,
                                           halo=est.local_halo).fit(sub.positions, sub.forces).predict(kp, True)
        t_local = time.thread_time() - c
        truth = sim.true_field(sim.pwm, kp)
        row = {'fans': n_side ** 2, 'key_points': len(kp), 'samples': n_samples, 'gp_samples': len(sub.forces),
               'exact_cpu_s': t_exact, 'local_cpu_s': t_local,
               'mean_diff_rms_N': float(np.sqrt(np.mean((ml - me) ** 2))),
               'mean_diff_max_N': float(np.max(np.abs(ml - me))),
               'std_diff_max_N': float(np.max(np.abs(sl - se))),
               'exact_error_rms_N': float(np.sqrt(np.mean((me - truth) ** 2))),
               'local_error_rms_N': float(np.sqrt(np.mean((ml - truth) ** 2)))}
        out.append(row)
        print(f"  GP {row['gp_samples']} samples: exact {t_exact:.2f} s, local {t_local:.2f} s; "
              f"mean differs by {row['mean_diff_rms_N']:.4f} N rms ({row['mean_diff_max_N']:.3f} max); "
              f"error vs truth exact {row['exact_error_rms_N']:.3f} N, local {row['local_error_rms_N']:.3f} N",
              flush=True)
    return out


def plot(series, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for ax, (name, label) in zip(axes, (('fans', 'fans (n x n wall, key points and samples grow with area)'),
                                        ('key_points', 'key points (36 x 36 wall, 50,000 samples)'),
                                        ('samples', 'samples per sweep (36 x 36 wall, 10,000 key points)'))):
        rows = series.get(name, [])
        if not rows:
            continue
        x = [r[name] for r in rows]
        for key, style, lab in (('estimate_cpu_s', 'o-', 'estimate'), ('update_cpu_s', 's-', 'update'),
                                ('total_cpu_s', 'k^-', 'estimate + update')):
            ax.loglog(x, [r[key] for r in rows], style, label=lab)
        ax.axhline(2.0, color='r', ls=':', lw=1, label='2 s target')
        ax.set_xticks(x)
        ax.set_xticklabels([f'{v:,}' for v in x], fontsize=7, rotation=30)
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel(label, fontsize=8)
        ax.set_ylabel('CPU time per iteration [s]')
        ax.grid(True, which='both', alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle('wind_shaper adaptive update: time per iteration (single thread, setup excluded)')
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f'wrote {path}')


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--series', action='store_true')
    ap.add_argument('--gp-accuracy', action='store_true')
    ap.add_argument('--iterations', type=int, default=4)
    ap.add_argument('--quick', action='store_true', help='a 6 x 6 wall, 289 key points, 1,390 samples, '
                    'no memory run (a smoke test: seconds)')
    ap.add_argument('--json', default=None, help='results file (default bench/out/scale.json, '
                    'bench/out/scale_quick.json with --quick)')
    ap.add_argument('--plot', default='docs/scaling.png')
    ap.add_argument('--replot', action='store_true', help='only redraw the plot from --json')
    args = ap.parse_args(argv)
    if args.json is None:
        args.json = 'bench/out/scale_quick.json' if args.quick else 'bench/out/scale.json'
    if args.quick:
        print('6 x 6 wall, 289 key points, 1,390 samples per sweep:')
        quick = run(6, 289, 1390, iterations=2)
        print(f"  => estimate {quick['estimate_cpu_s']:.3f} s + update {quick['update_cpu_s']:.3f} s = "
              f"{quick['total_cpu_s']:.3f} s CPU per iteration")
        merge_json(args.json, {'wall_6x6': quick})
        print(f'wrote {args.json}')
        return
    if args.replot:
        series = (read_json(args.json) or {}).get('series')
        if not series:
            raise SystemExit(f'{args.json} holds no --series results: run `python bench/scale.py --series` first')
        plot(series, args.plot)
        return
    doc = {}
    if args.gp_accuracy:
        print('Local GP vs exact GP:')
        doc['gp_accuracy'] = gp_accuracy()
    print('36 x 36 wall, 10,000 key points, 50,000 samples per sweep:')
    main_run = run(36, 10_000, 50_000, iterations=args.iterations)
    print('  the same with tracemalloc on (peak memory of estimate + update):')
    mem_run = run(36, 10_000, 50_000, iterations=3, truth=False, memory=True)
    main_run['peak_traced_MB'] = mem_run['peak_traced_MB']
    main_run['peak_traced_MB_per_iteration'] = [r['peak_traced_MB'] for r in mem_run['iterations']]
    doc['wall_36x36'] = main_run
    print(f"  => estimate {main_run['estimate_cpu_s']:.2f} s + update {main_run['update_cpu_s']:.2f} s = "
          f"{main_run['total_cpu_s']:.2f} s CPU per iteration ({main_run['total_wall_s']:.2f} s wall); "
          f"setup once per run {main_run['setup_cpu_s']:.2f} s; peak {main_run['peak_traced_MB']:.0f} MB traced "
          f"(first iteration, with the setup), {main_run['max_rss_MB']:.0f} MB process")
    if args.series:
        series = {'fans': [], 'key_points': [], 'samples': []}
        for n_side in (6, 12, 18, 24, 30):
            n_key = int(round(10_000 * (n_side / 36) ** 2))
            series['fans'].append(run(n_side, n_key, 5 * n_key, iterations=3, truth=False))
        series['fans'].append(main_run)
        for n_key in (2_500, 5_000, 20_000):
            series['key_points'].append(run(36, n_key, 50_000, iterations=3, truth=False))
        series['key_points'].append(main_run)
        series['key_points'].sort(key=lambda r: r['key_points'])
        for n_samples in (12_500, 25_000, 100_000, 200_000):
            series['samples'].append(run(36, 10_000, n_samples, iterations=3, truth=False))
        series['samples'].append(main_run)
        series['samples'].sort(key=lambda r: r['samples'])
        doc['series'] = series
        plot(series, args.plot)
    if args.json:
        merge_json(args.json, doc)
        print(f'wrote {args.json} ({", ".join(doc)}; other results kept)')


def read_json(path) -> dict | None:
    """The results file, or None when there is none yet."""
    path = Path(path)
    return json.loads(path.read_text()) if path.is_file() else None


def merge_json(path, doc: dict) -> dict:
    """Write ``doc``'s sections into the results file at ``path``, keeping the sections this run
    did not measure (a --gp-accuracy run keeps the --series data); return the merged document."""
    path = Path(path)
    merged = read_json(path) or {}
    merged.update(doc)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + '.tmp')
    tmp.write_text(json.dumps(merged, indent=1, default=float))
    tmp.replace(path)
    return merged


if __name__ == '__main__':
    main()
