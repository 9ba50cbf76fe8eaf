"""Held-out random tunnels: the shipped default against the flat start on tunnel models drawn at
random from the simulator's physics, none of them chosen by hand.

Every tunnel is the default rig with ``--effects`` (3) distinct simulator effects drawn from
``CATALOGUE``, each with its parameters drawn from a range a real tunnel could show (a weak fan
loses 5-30 % of its thrust, a starved plenum couples 0.3-0.8, a dead band is 0.04-0.12 PWM, a
tilted fan lands 2-5 cm off, ...; fans and directions drawn too). The sensing and timing
faults are left out: this benchmark is about the flow. The draw depends on ``--seed`` alone,
so a tunnel can be rebuilt and each is written as a tunnel file (``bench/convergence.py
--tunnel FILE``, beside the results) for a closer look.

Each tunnel is then benchmarked as ``bench/convergence.py --tunnel`` does: its prior
commissioned from 6 designed sweeps, zeta* (the best error the fans can reach) found on the
noise-free field, and the shipped default (warm start) and the flat start (every fan at 0.5,
the same rule) run on the noisy simulator for every seed. The criteria are
convergence.py's: the shipped default never more than 2 % behind the flat start at any k >= 2
(medians over seeds) and within 5 % of the optimum by k = 2 wherever the flat start is by k = 4.

Usage: python bench/random_tunnels.py [--count 12] [--seed 2026] [--effects 3] [--seeds 5]
                                      [--iterations 12] [--targets uniform,parabolic,gaussian@LM1]
                                      [--set NAME=VALUE ...] [--jobs N] [--quick] [--json FILE]
       python bench/random_tunnels.py --summary-from bench/out/random_tunnels.json
       python bench/random_tunnels.py --seed 2033 --shared-curve-verdicts [--set shared_curve_sd=0.1]
Results: bench/out/random_tunnels.json (--quick: random_tunnels_quick.json), the tunnel files in
bench/out/random_tunnels/.
"""
from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
os.environ.setdefault('OMP_NUM_THREADS', '1')

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import convergence  # noqa: E402

#: the default rig's fans (config/tunnel.yaml)
FANS = ['LM1', 'HM1', 'LM2', 'HM2', 'LM3', 'HM3', 'CM']


def _u(rng, low, high, digits=3):
    return round(float(rng.uniform(low, high)), digits)


def _fan(rng, fans=FANS):
    return str(rng.choice(fans))


def _angle(rng):
    return _u(rng, 0.0, 360.0, 1)


#: effect name -> a draw of its parameters (rng -> dict). The ranges are what a tunnel could
#: plausibly show, set from the effects' own documentation, not from how the shaping fares.
CATALOGUE = {
    'weak_fan': lambda r: {'fan': _fan(r), 'gain': _u(r, 0.7, 0.95)},
    'tilted_fan': lambda r: {'fan': _fan(r), 'shift': [_u(r, -0.05, 0.05), _u(r, -0.05, 0.05)]},
    'elongated_footprint': lambda r: {'fan': _fan(r), 'ratio': _u(r, 1.2, 2.0),
                                      'angle': _u(r, -3.1, 3.1)},
    'dead_band': lambda r: {'threshold': _u(r, 0.04, 0.12)},
    'swirl': lambda r: {'gain': _u(r, -0.6, 0.6)},
    'quadratic_swirl': lambda r: {'gain': _u(r, -0.5, 0.5), 'curvature': _u(r, -1.5, 1.5)},
    'wall_boundary_layer': lambda r: {'thickness': _u(r, 0.03, 0.08)},
    'merging_jets': lambda r: {'strength': _u(r, 0.2, 0.7)},
    'jet_interaction': lambda r: {'strength': _u(r, 0.1, 0.5)},
    'honeycomb_blockage': lambda r: {'x': _u(r, -0.15, 0.15), 'y': _u(r, -0.15, 0.15),
                                     'radius': _u(r, 0.03, 0.08), 'depth': _u(r, 0.2, 0.5)},
    'background_draft': lambda r: {'force': _u(r, -0.3, 0.4)},
    'ceiling_downwash': lambda r: {'share': _u(r, 0.05, 0.2)},
    'coanda_attachment': lambda r: {'pull': _u(r, 0.02, 0.06)},
    'coflow_carry': lambda r: {'carry': _u(r, 0.1, 0.4)},
    'diffuser_separation': lambda r: {'depth': _u(r, 0.15, 0.4), 'direction': _angle(r)},
    'drag_law': lambda r: {'exponent': _u(r, 0.1, 0.35)},
    'flow_screen': lambda r: {'share': _u(r, 0.15, 0.5)},
    'esc_crosstalk': lambda r: dict(zip(('fan', 'source'), map(str, r.choice(FANS, 2, replace=False))),
                                    coupling=_u(r, 0.1, 0.3)),
    'esc_current_limit': lambda r: {'ceiling': _u(r, 3.0, 5.0), 'spread': _u(r, 0.1, 0.3),
                                    'seed': int(r.integers(1000))},
    'hub_shadow': lambda r: {'depth': _u(r, 0.15, 0.4)},
    'jet_confinement': lambda r: {'squeeze': _u(r, 0.1, 0.4)},
    'jet_deflection': lambda r: {'pull': _u(r, 0.02, 0.06)},
    'jet_pairing': lambda r: {'pull': _u(r, 0.02, 0.06)},
    'jet_spreading': lambda r: {'exponent': _u(r, -0.2, 0.25)},
    'neighbour_starvation': lambda r: {'coupling': _u(r, 0.15, 0.4)},
    'plenum_starvation': lambda r: {'coupling': _u(r, 0.3, 0.8)},
    'recirculation_core': lambda r: {'share': _u(r, 0.1, 0.4)},
    'side_draft': lambda r: {'dx': _u(r, -0.08, 0.08), 'dy': _u(r, -0.08, 0.08)},
    'side_inlet': lambda r: {'coupling': _u(r, 0.2, 0.5), 'direction': _angle(r)},
    'stall_dip': lambda r: {'depth': _u(r, 0.1, 0.3), 'at': _u(r, 0.25, 0.55),
                            'width': _u(r, 0.05, 0.12), 'seed': int(r.integers(1000))},
    'stand_wake': lambda r: {'y': _u(r, -0.1, 0.1), 'depth': _u(r, 0.2, 0.4)},
    'supply_sag': lambda r: {'sag': _u(r, 0.1, 0.35)},
    'thermal_gradient': lambda r: {'slope': _u(r, -0.2, 0.2), 'direction': _angle(r)},
    'unequal_curves': lambda r: {'spread': _u(r, 0.1, 0.3), 'seed': int(r.integers(1000))},
    'vane_ripple': lambda r: {'depth': _u(r, 0.05, 0.2), 'wavelength': _u(r, 0.2, 0.5),
                              'direction': _angle(r), 'phase': _u(r, -3.0, 3.0)},
    'wall_leak': lambda r: {'angle': _angle(r), 'share': _u(r, 0.2, 0.6)},
    'wall_reflection': lambda r: {'share': _u(r, 0.3, 0.7)},
    'wall_return_flow': lambda r: {'share': _u(r, 0.1, 0.4)},
}

#: the simulator's effects no tunnel here draws, and why
LEFT_OUT = {
    'mocap_latency': 'a fault of the recording (motion capture late), not of the flow',
    'sensor_zero_drift': 'a fault of the force sensor in time (the workbench checks for it)',
    'unsettled_fans': 'a fault of the sweep\'s timing (the workbench checks for it)',
}


def draw_tunnels(count: int, seed: int, n_effects: int) -> list[dict]:
    """``count`` tunnels of ``n_effects`` distinct effects each: [{name, effects}]."""
    rng = np.random.default_rng(seed)
    names = sorted(CATALOGUE)
    tunnels = []
    for i in range(count):
        picked = [str(n) for n in rng.choice(names, n_effects, replace=False)]
        effects = [{'name': n, **CATALOGUE[n](rng)} for n in picked]
        tunnels.append({'name': f'random {seed}-{i}: ' + ' + '.join(picked), 'effects': effects})
    return tunnels


def benchmark_tunnel(job) -> list[dict]:
    """One tunnel's rows: (tunnel, targets, methods, seeds, iterations, quick) -> a row per
    target, as bench/convergence.py makes them (the prior commissioned on the tunnel first)."""
    tunnel, targets, methods, seeds, iterations, quick, first_seed = job
    convergence.OWN_TUNNELS.clear()
    convergence.OWN_TUNNELS[tunnel['name']] = (tunnel['effects'], targets)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        plant = convergence.make_plants([tunnel['name']], Path(tmp))[0]
        kp = plant.setup.geometry.key_points
        for spec in targets:
            tv = plant.setup.make_target(spec).values(kp)
            zs, U_star = convergence.zeta_star(plant, tv, starts=3 if quick else 40)
            runs = {name: [convergence.run_method(plant, tv, cfg, s, iterations)
                           for s in range(first_seed, first_seed + seeds)]
                    for name, cfg in methods.items()}
            zs, _ = convergence.lower_by_runs(plant, tv, zs, U_star,
                                              [r for rs in runs.values() for r in rs])
            row = {'case': f"{tunnel['name']}, {spec}", 'plant': tunnel['name'], 'target': spec,
                   'effects': tunnel['effects'], 'zeta_star_N2': zs,
                   'model_error_N': plant.model_error,
                   'methods': {name: convergence.summarise(rs, zs) for name, rs in runs.items()}}
            rows.append(row)
            convergence.print_row(row)
    return rows


def shared_curve_verdict(job) -> bool:
    """Whether the update bends the curve every fan shares on this tunnel (``shared_curve_sd``
    from ``rule``): the prior commissioned as for the benchmark, then one update from the flat
    start, whose fit always takes the commissioning's maps. The verdict rests on those maps
    alone, so it is the same at every step, for every target and both starts; a tunnel where it
    is False runs exactly as without the setting."""
    tunnel, rule = job
    convergence.OWN_TUNNELS.clear()
    convergence.OWN_TUNNELS[tunnel['name']] = (tunnel['effects'], ['uniform'])
    with tempfile.TemporaryDirectory() as tmp:
        plant = convergence.make_plants([tunnel['name']], Path(tmp))[0]
        target = plant.setup.make_target('uniform').values(plant.setup.geometry.key_points)
        loop = convergence.make_loop(plant, target, {'rule': rule, 'u0': 0.5}, plant.sim(0))
        return bool(loop.iterate(update=True).info.get('shared_curve'))


def print_results(rows):
    """The shipped default against the flat start per case (convergence.py's verdicts), then
    one line per case: the ratios at k = 0, 1, 2, 4, 12, plate seconds, the std's calibration."""
    convergence.print_warm_checks(rows)
    print()
    iterations = len(rows[0]['methods'][next(iter(rows[0]['methods']))]['median_ratio']) - 1 if rows else 0
    convergence.print_summary(rows, ks=tuple(k for k in (0, 1, 2, 4, 12) if k <= iterations))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--count', type=int, default=12, help='tunnels to draw')
    ap.add_argument('--seed', type=int, default=2026, help='the draw of the tunnels')
    ap.add_argument('--effects', type=int, default=3, help='effects per tunnel')
    ap.add_argument('--seeds', type=int, default=5,
                    help='runs per method and case (from 4 on, each verdict also weighs the gap '
                         'against the flat start\'s own gap between its two halves of seeds)')
    ap.add_argument('--first-seed', type=int, default=0,
                    help="the runs' seeds are FIRST .. FIRST + seeds - 1 (for "
                         "`convergence.py --self-check`)")
    ap.add_argument('--iterations', type=int, default=12)
    ap.add_argument('--targets', default=','.join(convergence.DEFAULT_OWN_TARGETS))
    ap.add_argument('--methods', default=f'{convergence.SHIPPED},flat')
    ap.add_argument('--quick', action='store_true',
                    help='one tunnel, its first target, one seed, two iterations (a smoke run)')
    ap.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                    help='a setting of the adaptive update (shaping.update) for both starts, e.g. '
                         'load_sd=0 (repeatable)')
    ap.add_argument('--jobs', type=int, default=1, help='tunnels benchmarked at once (processes)')
    ap.add_argument('--json', default=None)
    ap.add_argument('--summary-from', default=None, metavar='JSON',
                    help='print the verdicts and the table of a results file, run nothing')
    ap.add_argument('--shared-curve-verdicts', action='store_true',
                    help='per tunnel, only whether the update bends the curve every fan shares '
                         '(shared_curve_sd, 0.1 unless --set): the tunnels where that setting '
                         'changes a run; seconds per tunnel')
    args = ap.parse_args(argv)
    if args.summary_from:
        print_results(json.loads(Path(args.summary_from).read_text())['cases'])
        return
    if not 1 <= args.effects <= len(CATALOGUE):
        ap.error(f'--effects must be 1..{len(CATALOGUE)}, got {args.effects}')
    if args.quick:
        args.count, args.seeds, args.iterations = 1, 1, 2
        args.targets = args.targets.split(',')[0]
    args.json = args.json or f"bench/out/random_tunnels{'_quick' if args.quick else ''}.json"
    targets = args.targets.split(',')
    methods = {}
    for m in args.methods.split(','):
        if m not in convergence.METHODS:
            ap.error(f'unknown method {m!r}; choose from {", ".join(convergence.METHODS)}')
        methods[m] = {**convergence.METHODS[m], 'rule': dict(convergence.METHODS[m]['rule'])}
    for kv in args.set:
        key, sep, value = kv.partition('=')
        if not sep or not key:
            ap.error(f'--set takes NAME=VALUE, got {kv!r}')
        for cfg in methods.values():
            if cfg['rule']['method'] == 'adaptive':
                cfg['rule'][key] = convergence._value(value)
    from wind_shaper.app import Setup
    from wind_shaper.core.errors import ConfigError
    setup = Setup.load()
    try:   # a bad setting or target stops here, before the first run
        for cfg in methods.values():
            setup.shaping.make_rule(**cfg['rule'])
        for spec in targets:
            setup.make_target(spec)
    except (ConfigError, TypeError, ValueError) as exc:
        ap.error(str(exc))
    tunnels = draw_tunnels(args.count, args.seed, args.effects)
    files = Path(args.json).parent / 'random_tunnels'
    files.mkdir(parents=True, exist_ok=True)
    for i, tunnel in enumerate(tunnels):
        (files / f'tunnel_{args.seed}_{i}.yaml').write_text(
            yaml.safe_dump({**tunnel, 'targets': targets}, sort_keys=False))
    t0 = time.perf_counter()
    if args.shared_curve_verdicts:
        rule = {'shared_curve_sd': 0.1, **methods[next(iter(methods))]['rule']}
        verdicts = [shared_curve_verdict((tunnel, rule)) for tunnel in tunnels]
        for tunnel, bent in zip(tunnels, verdicts):
            print(f"{tunnel['name']}: {'bent' if bent else 'straight'}")
        meta = {'count': args.count, 'seed': args.seed, 'effects': args.effects, 'rule': rule}
        Path(args.json).write_text(json.dumps({'meta': meta, 'shared_curve': {
            t['name']: v for t, v in zip(tunnels, verdicts)}}, indent=1))
        print(f'wrote {args.json}')
        return
    jobs = [(tunnel, targets, methods, args.seeds, args.iterations, args.quick, args.first_seed)
            for tunnel in tunnels]
    if args.jobs > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(args.jobs) as pool:
            done = list(pool.map(benchmark_tunnel, jobs))
    else:
        done = [benchmark_tunnel(job) for job in jobs]
    rows = [row for tunnel_rows in done for row in tunnel_rows]
    print_results(rows)
    print(f'\n({time.perf_counter() - t0:.0f} s)')
    meta = {'count': args.count, 'seed': args.seed, 'effects': args.effects, 'seeds': args.seeds, 'first_seed': args.first_seed,
            'iterations': args.iterations, 'targets': targets, 'methods': methods,
            'definitions': __doc__}
    Path(args.json).write_text(json.dumps({'meta': meta, 'cases': rows}, indent=1, default=str))
    print(f'wrote {args.json}')


if __name__ == '__main__':
    main()
