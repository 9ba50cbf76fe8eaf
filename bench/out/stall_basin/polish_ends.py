"""Is where a run ends a local minimum of the true error?  For each case: run the shipped default
and the flat start (seeds), take the commands at k = 12, polish each with a local bounded
least-squares on the TRUE field from there, and walk the straight line between the two ends.
usage (from the repository root, PYTHONPATH=.): python bench/out/stall_basin/polish_ends.py SPEC TARGET SEEDS   (SPEC: tunnel yaml | draw:SEED:IDX | plant name)"""
import sys, json, tempfile
from pathlib import Path
import numpy as np
from scipy.optimize import least_squares
sys.path.insert(0, 'bench')
import convergence as cv
spec, target, seeds = sys.argv[1], sys.argv[2], [int(s) for s in sys.argv[3].split(',')]
if spec.startswith('draw:'):
    import random_tunnels as rt
    _, d, i = spec.split(':')
    t = rt.draw_tunnels(12, int(d), 3)[int(i)]
    name = t['name']; cv.OWN_TUNNELS[name] = (t['effects'], [target])
elif spec.endswith('.yaml'):
    name, eff, tg = cv.load_tunnel_file(spec); cv.OWN_TUNNELS[name] = (eff, tg)
else:
    name = spec
with tempfile.TemporaryDirectory() as tmp:
    plant = cv.make_plants([name], Path(tmp))[0]
    kp = plant.setup.geometry.key_points
    tv = plant.setup.make_target(target).values(kp)
    zs, U_star = cv.zeta_star(plant, tv)
    residual, on, lo, hi = cv._true_residual(plant, tv)
    f = lambda u: float(np.mean(residual(u) ** 2)) / zs
    out = {'case': f'{name}, {target}', 'U_star': np.round(U_star, 3).tolist(), 'seeds': []}
    for seed in seeds:
        ends = {}
        for m in ('warm+short', 'flat'):
            cfg = {**cv.METHODS[m], 'rule': dict(cv.METHODS[m]['rule'])}
            sim = plant.sim(seed)
            loop = cv.make_loop(plant, tv, cfg, cv._TimedTunnel(sim), short=True)
            for i in range(13):
                rec = loop.iterate(update=i < 12)
            u = np.asarray(rec.pwm, float)[on]
            sol = least_squares(residual, u, bounds=(lo, hi), diff_step=1e-4, xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=400)
            ends[m] = (u, sol.x)
        us, uf = ends['warm+short'][0], ends['flat'][0]
        ps, pf = ends['warm+short'][1], ends['flat'][1]
        line = [f(ps + t * (pf - ps)) for t in np.linspace(0, 1, 41)]
        row = {'seed': seed, 'shipped_end': round(f(us), 4), 'shipped_polished': round(f(ps), 4),
               'flat_end': round(f(uf), 4), 'flat_polished': round(f(pf), 4),
               'barrier_between_polished': round(max(line) - max(line[0], line[-1]), 4),
               'polished_apart_pwm': round(float(np.max(np.abs(ps - pf))), 3),
               'shipped_polished_U': np.round(ps, 3).tolist(), 'flat_polished_U': np.round(pf, 3).tolist()}
        out['seeds'].append(row)
        print(json.dumps(row), flush=True)
    print(json.dumps(out))
