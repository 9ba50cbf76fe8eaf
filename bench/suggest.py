"""Do the sweeps the diagnosis suggests teach it more than as many random ones?

    .venv/bin/python bench/suggest.py               # 7 effects x 10 seeds; ~10 min on 2 cores
    .venv/bin/python bench/suggest.py --seeds 3
    .venv/bin/python bench/suggest.py --quick      # one effect, one seed, short sweeps: checks it runs

For each effect of the library (switched on alone in the simulated tunnel, at its default
magnitude) and seed: 6 designed sweeps (``simulated_sweeps``: fans off first and last, a Latin
hypercube over 0-90 % PWM between), a diagnosis against the commissioned reference, then 4 more
sweeps either as ``suggest_sweeps`` proposes them (goal auto) or at random Latin-hypercube
commands over the same range, and the diagnosis again on all 10. Reported per arm: how often the
effect's family is named (found), how often another is (wrong), and for the runs where the
effect is found in both arms, the median ratio of its parameter's standard error (suggested /
random; below 1: the suggested sweeps pin it down better). Seeds from 200, away from the tests'
and the detection bench's. Writes bench/out/suggest.json and prints a Markdown table.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

EFFECTS = ['tilted_fan', 'weak_fan', 'swirl', 'dead_band', 'wall_boundary_layer', 'jet_interaction',
           'elongated_footprint']
FIRST, MORE, HIGH = 6, 4, 0.9


def _judge(d, reference, setup, effect):
    from wind_shaper.workbench.library import candidate_for_hidden_effect, default_library
    family = {c.name: c.family for c in default_library().candidates(reference, setup.geometry)}
    expected = family[candidate_for_hidden_effect(effect)[0]]
    named = [t.candidate.name for t in d.steps_]
    hit = next((t for t in d.steps_ if family.get(t.candidate.name) == expected), None)
    rel = None
    if hit is not None:  # the finding's largest parameter, relative standard error
        ratios = [abs(float(np.asarray(hit.std[k]).ravel()[0])) /
                  max(abs(float(np.asarray(v).ravel()[0])), 1e-9) for k, v in hit.params.items()
                  if k in hit.std]
        rel = float(min(ratios)) if ratios else None
    return {'named': named, 'found': hit is not None,
            'wrong': sorted(n for n in named if family.get(n, n) != expected), 'rel_std': rel}


def run_one(job) -> dict:
    effect_name, seed, n_samples, pool = job
    from wind_shaper.app import Setup
    from wind_shaper.experiment import design_commands
    from wind_shaper.sim import make_effect
    from wind_shaper.workbench.commands import simulated_sweeps
    from wind_shaper.workbench.data import from_sim
    from wind_shaper.workbench.diagnose import Diagnosis
    from wind_shaper.workbench.suggest import suggest_sweeps
    setup = Setup.load()
    reference = setup.load_model(setup.config_dir / 'reference.yaml')
    effect = make_effect(effect_name)
    sim = setup.make_sim(seed=seed, effects=[effect])
    first = simulated_sweeps(sim, FIRST, seed=seed, high=HIGH, n_samples=n_samples)
    d0 = Diagnosis().fit(reference, first, setup.geometry)
    t0 = time.process_time()
    s = suggest_sweeps(d0, MORE, 0.0, HIGH, seed=seed, pool=pool)
    suggest_cpu = time.process_time() - t0
    fans = setup.geometry.fans
    random_U = design_commands(fans.n_fans, MORE, high=HIGH, seed=seed + 1000, enabled=fans.enabled)
    out = {'effect': effect_name, 'seed': seed, 'goal': s.goal, 'suggest_cpu_s': round(suggest_cpu, 2),
           'first': _judge(d0, reference, setup, effect)}
    for arm, U in (('suggested', s.design.commands), ('random', random_U)):
        more = from_sim(sim, U, n_samples=n_samples)
        d = Diagnosis().fit(reference, first + more, setup.geometry)
        out[arm] = _judge(d, reference, setup, effect)
    return out


def table(rows) -> str:
    out = ['| effect | runs | found after 6 | found +4 suggested | found +4 random | wrong +4 suggested | '
           'wrong +4 random | std ratio suggested/random (median) |', '|---|---|---|---|---|---|---|---|']
    for effect in dict.fromkeys(r['effect'] for r in rows):
        rs = [r for r in rows if r['effect'] == effect]
        n = len(rs)
        ratios = [r['suggested']['rel_std'] / r['random']['rel_std'] for r in rs
                  if r['suggested']['rel_std'] and r['random']['rel_std']]
        ratio = f'{np.median(ratios):.2f} ({len(ratios)} runs)' if ratios else '-'
        out.append(f'| {effect} | {n} | {sum(r["first"]["found"] for r in rs)}/{n} | '
                   f'{sum(r["suggested"]["found"] for r in rs)}/{n} | {sum(r["random"]["found"] for r in rs)}/{n} | '
                   f'{sum(bool(r["suggested"]["wrong"]) for r in rs)}/{n} | '
                   f'{sum(bool(r["random"]["wrong"]) for r in rs)}/{n} | {ratio} |')
    return '\n'.join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--seeds', type=int, default=10)
    p.add_argument('--jobs', type=int, default=2)
    p.add_argument('--effects', default=','.join(EFFECTS),
                   help='comma-separated effects of the library (default: all seven)')
    p.add_argument('--samples', type=int, default=1000, help='plate samples per sweep')
    p.add_argument('--pool', type=int, default=400,
                   help="candidate commands the suggestion chooses from (suggest_sweeps' pool)")
    p.add_argument('--quick', action='store_true',
                   help='weak_fan, one seed, 600 samples per sweep, a pool of 50: checks the script runs')
    p.add_argument('--json', type=Path, default=ROOT / 'bench' / 'out' / 'suggest.json')
    args = p.parse_args(argv)
    if args.quick:
        args.seeds, args.effects, args.samples, args.pool, args.jobs = 1, 'weak_fan', 600, 50, 1
    effects = [e for e in args.effects.split(',') if e]
    if not effects or set(effects) - set(EFFECTS):
        p.error(f'--effects: choose from {", ".join(EFFECTS)}')
    jobs = [(e, 200 + s, args.samples, args.pool) for e in effects for s in range(args.seeds)]
    t0 = time.time()
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_one, jobs))
    text = table(rows)
    print(text)
    totals = {arm: sum(r[arm]['found'] for r in rows) for arm in ('first', 'suggested', 'random')}
    print(f'\nfound: {totals["first"]}/{len(rows)} after {FIRST} sweeps, {totals["suggested"]}/{len(rows)} '
          f'with {MORE} suggested, {totals["random"]}/{len(rows)} with {MORE} random; goals: '
          f'{ {g: sum(r["goal"] == g for r in rows) for g in ("separate", "shrink", "explore")} }; '
          f'{len(rows)} runs in {time.time() - t0:.0f} s')
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({'seeds': args.seeds, 'samples': args.samples, 'pool': args.pool, 'rows': rows, 'table': text}, indent=1))
    print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
