"""Commissioning the prior: the paper's held-plate batch against designed moving-plate sweeps.

    .venv/bin/python bench/commissioning.py              # designed sweeps through the node graph; ~10 min
    .venv/bin/python bench/commissioning.py --in-process # everything on the in-process simulator; ~2 min
    .venv/bin/python bench/commissioning.py --quick      # lhs:3 of 3 s sweeps through the graph, one
                                                         # shaping seed: checks the script runs

Arms:

* held: the paper's calibration batch, 231 plate positions x 20 samples (each enabled fan alone
  at 0-80 % PWM over its hub, and at 50 % at 16 offsets around it), the paper's prior fitted to
  it (``model.calibration``), on the in-process simulator. Its plate time is counted with a
  stated model: each position takes ``--hold-s`` (default 5 s: carry the plate there, hold it
  still within tolerance) plus its 20 samples at the rate.
* held through the graph (``--held-graph``): `wind-shaper calibrate --held --auto` on the same
  graph, the simulated rig's place service standing in for a motion stage (levels within
  shaping.yaml's range and points inside the sweep disc only); wall time measured.
* designed N (3, 6, 12): `wind-shaper collect --design lhs:N` (fans off first and last, a Latin
  hypercube over shaping.yaml's range between) through `wind-shaper up --sim` (MAVLink, Net F/T
  RDT and mocap on loopback; sweeps of ``--sweep-s``), then `wind-shaper calibrate --data` on the
  experiment folder. Plate time: N x sweep duration; wall time: measured, collect call to answer.
  With --in-process the same designs are swept on the in-process simulator (1000 samples each).

Measures of each prior: RMSE [N] of its prediction against the cell means (3 cm) of 8 held-out
Latin-hypercube sweeps of the same tunnel (other seeds; the noise is in this number for every
arm alike), and the true-field RMSE [N] of the shaping loop (parabolic target; the adaptive rule,
which corrects the prior's Jacobian from the data, and the paper's Algorithm 1, which trusts it)
after 2 and 4 iterations started from that prior, median over ``--seeds`` simulator seeds.
The simulated tunnel is one build (sim.yaml build_seed); seeds change the noise and the path.
Writes bench/out/commissioning.json and prints a Markdown table.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from wind_shaper.app import Setup, shape_on_sim  # noqa: E402
from wind_shaper.experiment import make_design  # noqa: E402
from wind_shaper.model import CalibrationPlan, collect_calibration, fit_model as fit_held, paper_prior  # noqa: E402
from wind_shaper.workbench.calibrate import calibrate_default_prior  # noqa: E402
from wind_shaper.workbench.data import from_sim, load_sweeps  # noqa: E402

COUNTS = (3, 6, 12)


def heldout_rmse(model, test) -> float:
    data = test.fit_data(0.03)
    r = model(data.U, data.Z) - data.y
    return float(np.sqrt(np.mean(r ** 2)))


def jacobian_error(setup, model, u: float = 0.5, h: float = 0.01) -> float:
    """Relative error of the prior's Jacobian at the key points against the simulated tunnel's
    true one (central differences), all fans at ``u``: ||J_model - J_true||_F / ||J_true||_F."""
    sim = setup.make_sim(seed=0)
    kp = setup.geometry.key_points
    n = setup.geometry.fans.n_fans
    U = np.full(n, u)
    J_true = np.stack([(sim.true_field(U + h * e, kp) - sim.true_field(U - h * e, kp)) / (2 * h)
                       for e in np.eye(n)], axis=1)
    J_model = model.jacobian(np.tile(U, (len(kp), 1)), kp)
    return float(np.linalg.norm(J_model - J_true) / np.linalg.norm(J_true))


def shaping(setup, model, seeds, method: str) -> dict:
    at = {2: [], 4: []}
    for seed in seeds:
        records, _ = shape_on_sim(setup, 'parabolic', iterations=4, seed=seed, model=model,
                                  rule_overrides={'method': method})
        for k in at:
            at[k].append(float(np.sqrt(records[k].true_error)))
    return {k: float(np.median(v)) for k, v in at.items()}


def graph_designs(setup, counts, sweep_s: float, log, held: bool = False) -> dict:
    """Collect lhs:N through `wind-shaper up --sim` for every N; {N: (SweepSet, wall_s)}; with
    ``held`` also the guided held-plate batch (`calibrate --held --auto`): {'held': (model,
    wall_s, points)}."""
    root = Path(tempfile.mkdtemp(prefix='ws-commission-'))
    env = dict(os.environ, ROS_DOMAIN_ID=os.environ.get('ROS_DOMAIN_ID') or str(60 + os.getpid() % 30),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    cli = [sys.executable, '-m', 'wind_shaper.cli.main']
    up = subprocess.Popen([*cli, 'up', '--sim', '--set', 'coordinator.settle_s=1.0'], cwd=root,
                          env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          start_new_session=True)
    out = {}
    try:
        deadline = time.monotonic() + 90
        for line in up.stdout:
            if re.search(r'all \d+ nodes are up', line):
                break
            if time.monotonic() > deadline:
                raise RuntimeError('the graph did not come up')
        for n in counts:
            t0 = time.monotonic()
            p = subprocess.run([*cli, 'collect', '--design', f'lhs:{n}', '--out', f'lhs{n}',
                                '--duration', str(sweep_s), '--no-bag', '--wait', '30'],
                               cwd=root, env=env, capture_output=True, text=True)
            wall = time.monotonic() - t0
            if p.returncode != 0:
                raise RuntimeError(f'collect lhs:{n} failed:\n{p.stdout}\n{p.stderr}')
            out[n] = (load_sweeps(root / 'runs' / f'lhs{n}', setup.geometry.fans.names), wall)
            log(f'lhs:{n} through the graph: {wall:.0f} s wall')
        if held:
            t0 = time.monotonic()
            p = subprocess.run([*cli, 'calibrate', '--held', '--auto', '--batch', 'held',
                                '--out', 'held.yaml', '--wait', '30'], cwd=root, env=env,
                               capture_output=True, text=True)
            wall = time.monotonic() - t0
            if p.returncode != 0:
                raise RuntimeError(f'calibrate --held failed:\n{p.stdout}\n{p.stderr}')
            points = int(re.search(r'on (\d+) held points', p.stdout).group(1))
            out['held'] = (setup.load_model(root / 'held.yaml'), wall, points)
            log(f'held batch through the graph: {points} points, {wall:.0f} s wall')
    finally:
        os.killpg(up.pid, signal.SIGINT)
        try:
            up.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(up.pid, signal.SIGKILL)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--seeds', type=int, default=5, help='shaping seeds (default 5)')
    p.add_argument('--hold-s', type=float, default=5.0, help='time to place and still the plate '
                                                             'at one held position [s]')
    p.add_argument('--sweep-s', type=float, default=10.0, help='designed sweep duration [s]')
    p.add_argument('--in-process', action='store_true', help='designed sweeps on the in-process '
                                                             'simulator instead of the graph')
    p.add_argument('--held-graph', action='store_true',
                   help='also run the guided held-plate batch through the graph (calibrate --held '
                        '--auto, the simulated rig placing the plate; ~10 min more)')
    p.add_argument('--counts', type=int, nargs='+', default=list(COUNTS),
                   help=f'designed sweep counts N of lhs:N (default {" ".join(map(str, COUNTS))})')
    p.add_argument('--quick', action='store_true',
                   help='--seeds 1 --counts 3 --sweep-s 3: checks the script runs (about a minute)')
    p.add_argument('--json', type=Path, default=ROOT / 'bench' / 'out' / 'commissioning.json')
    args = p.parse_args(argv)
    if args.quick:
        args.seeds, args.counts, args.sweep_s = 1, [3], 3.0
    if min(args.counts) < 3:
        p.error('--counts: each design needs at least 3 sweeps (fans off first and last)')

    def log(text):
        print(text, file=sys.stderr, flush=True)

    setup = Setup.load()
    fans = setup.geometry.fans
    b = setup.shaping.bounds
    seeds = list(range(args.seeds))
    test_design = make_design('lhs:10', fans, b.u_min, b.u_max, seed=4242)
    test = from_sim(setup.make_sim(seed=4242), test_design.commands[1:-1], n_samples=1000)
    rows = []

    plan = CalibrationPlan()
    t0 = time.perf_counter()
    held_data = collect_calibration(setup.make_sim(seed=11), plan)
    fit = fit_held(paper_prior(fans), held_data)
    n_positions = int(np.sum(fans.enabled)) * (len(plan.levels) + 4 * len(plan.offsets))
    rate = float(setup.sim_config.get('sample_rate_hz', 50.0))
    rows.append({'arm': 'held-plate batch', 'positions': n_positions,
                 'plate_s': n_positions * (args.hold_s + plan.samples_per_point / rate),
                 'wall_s': None, 'compute_s': time.perf_counter() - t0,
                 'heldout_rmse_N': heldout_rmse(fit.model, test), **_shape_cols(setup, fit.model, seeds)})
    log(f'held: {rows[-1]}')

    if args.in_process:
        designs = {}
        for n in args.counts:
            d = make_design(f'lhs:{n}', fans, b.u_min, b.u_max, seed=0)
            designs[n] = (from_sim(setup.make_sim(seed=20 + n), d.commands, n_samples=1000), None)
    else:
        designs = graph_designs(setup, args.counts, args.sweep_s, log, held=args.held_graph)
    if 'held' in designs:
        model, wall, points = designs.pop('held')
        rows.append({'arm': f'held-plate batch through the graph ({points} points)',
                     'positions': points, 'plate_s': points * (args.hold_s + plan.samples_per_point / 100.0),
                     'wall_s': wall, 'compute_s': None, 'heldout_rmse_N': heldout_rmse(model, test),
                     **_shape_cols(setup, model, seeds)})
        log(f'held through the graph: {rows[-1]}')
    for n, (data, wall) in designs.items():
        t0 = time.perf_counter()
        cal = calibrate_default_prior(data, fans)
        sweep_s = args.sweep_s if not args.in_process else 1000 / rate
        rows.append({'arm': f'designed lhs:{n}', 'positions': None, 'plate_s': n * sweep_s,
                     'wall_s': wall, 'compute_s': time.perf_counter() - t0,
                     'heldout_rmse_N': heldout_rmse(cal.model, test),
                     **_shape_cols(setup, cal.model, seeds)})
        log(f'lhs:{n}: {rows[-1]}')
    shipped = setup.load_model()
    rows.append({'arm': 'shipped config/model.yaml (for scale)', 'positions': None, 'plate_s': None,
                 'wall_s': None, 'compute_s': None, 'heldout_rmse_N': heldout_rmse(shipped, test),
                 **_shape_cols(setup, shipped, seeds)})

    def cell(v, fmt):
        return '-' if v is None else format(v, fmt)
    lines = ['| prior from | plate time [s] | wall time [s] | held-out RMSE [N] | Jacobian error at 50 % | '
             'shaping k=2 / k=4, adaptive rule [N] | k=2 / k=4, paper\'s rule [N] |',
             '|---|---|---|---|---|---|---|']
    for r in rows:
        lines.append(f'| {r["arm"]} | {cell(r["plate_s"], ".0f")} | {cell(r["wall_s"], ".0f")} | '
                     f'{r["heldout_rmse_N"]:.3f} | {100 * r["jacobian_error"]:.0f} % | '
                     f'{r["k2_N"]:.3f} / {r["k4_N"]:.3f} | {r["paper_k2_N"]:.3f} / {r["paper_k4_N"]:.3f} |')
    text = '\n'.join(lines)
    print(text)
    print(f'\n(held-plate plate time: {args.hold_s:g} s per position + 20 samples at {rate:g} Hz; '
          f'designed: {"the graph, sweeps of %g s" % args.sweep_s if not args.in_process else "in-process, 1000 samples"}; '
          f'shaping: median over seeds {seeds})')
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({'rows': rows, 'table': text, 'hold_s': args.hold_s,
                                     'sweep_s': args.sweep_s, 'in_process': args.in_process}, indent=1))
    print(f'wrote {args.json}')
    return 0


def _shape_cols(setup, model, seeds) -> dict:
    a, p = shaping(setup, model, seeds, 'adaptive'), shaping(setup, model, seeds, 'paper')
    return {'k2_N': a[2], 'k4_N': a[4], 'paper_k2_N': p[2], 'paper_k4_N': p[4],
            'jacobian_error': jacobian_error(setup, model)}


if __name__ == '__main__':
    raise SystemExit(main())
