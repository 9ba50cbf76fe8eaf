"""Screen a rule setting on chosen landing_full cases: shipped only, seeds 0..S-1, against the
stored shipped and flat runs of the same seeds.  usage: screen.py CASES.txt OUT.json SEEDS [k=v ...]; ITERS=N in the environment: k up to N (12)"""
import sys, json, glob, tempfile, time
from pathlib import Path
import numpy as np
sys.path.insert(0, 'bench')
import convergence as cv
import random_tunnels as rt
cases_file, out, seeds = sys.argv[1], sys.argv[2], int(sys.argv[3])
sets = [kv.split('=', 1) for kv in sys.argv[4:]]
stored = {}
for f in [g for g in glob.glob('/work/main/bench/out/level_top/*.json') if 'screen' not in g and 'without' not in g] + ['/work/main/bench/out/twelfth/written_2026-12-04e.json', '/work/main/bench/out/eleventh/written_2026-12-04d.json', '/work/main/bench/out/draw_2037/random_tunnels_2037.json', '/work/main/bench/out/draw_2038/random_tunnels_2038.json', '/work/main/bench/out/thirteenth/written_2026-12-04f.json']:
    for r in json.load(open(f))['cases']:
        stored[r['case']] = r
written = {}
for f in glob.glob('bench/tunnels/written_*/*.yaml'):
    name, effects, targets = cv.load_tunnel_file(f)
    written[name] = (effects, targets)
wanted = [l.strip() for l in open(cases_file) if l.strip()]
by_plant = {}
for c in wanted:
    r = stored[c]
    by_plant.setdefault(r['plant'], []).append(r)
import os
METH = os.environ.get("METH", "warm+short")
cfg = {**cv.METHODS[METH], "rule": dict(cv.METHODS[METH]["rule"])}
for k, v in sets:
    cfg['rule'][k] = cv._value(v)
res = {}
t0 = time.time()
for pname, rows in by_plant.items():
    cv.OWN_TUNNELS.clear()
    if pname.startswith('random '):
        sd, idx = pname.split(':')[0].split()[1].split('-')
        t = rt.draw_tunnels(12, int(sd), 3)[int(idx)]
        assert t['name'] == pname, (t['name'], pname)
        cv.OWN_TUNNELS[pname] = (t['effects'], [r['target'] for r in rows])
    elif pname in written:
        cv.OWN_TUNNELS[pname] = written[pname]
    with tempfile.TemporaryDirectory() as tmp:
        plant = cv.make_plants([pname], Path(tmp))[0]
        kp = plant.setup.geometry.key_points
        for r in rows:
            tv = plant.setup.make_target(r['target']).values(kp)
            zs = r['zeta_star_N2']
            R = [np.array(cv.run_method(plant, tv, cfg, s, int(os.environ.get('ITERS', 12)))['mse']) / zs for s in range(seeds)]
            res[r['case']] = {'new': np.round(R, 4).tolist(),
                              'base': r['methods']['warm+short']['ratio_per_seed'][:seeds],
                              'flat': r['methods']['flat']['ratio_per_seed'][:seeds]}
            m = lambda x: np.median(np.array(x), 0)
            print(f"{r['case'][:60]:60s} k2 new {m(res[r['case']]['new'])[2]:.3f} base {m(res[r['case']]['base'])[2]:.3f} flat {m(res[r['case']]['flat'])[2]:.3f}  ({time.time()-t0:.0f}s)", flush=True)
            json.dump({'sets': sets, 'seeds': seeds, 'cases': res}, open(out, 'w'))
print('done', flush=True)
