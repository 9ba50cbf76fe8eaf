"""Per stored case: true error ratio at each commissioning level map's command vs the shipped k0 median."""
import sys, json, glob, tempfile
from pathlib import Path
import numpy as np
sys.path.insert(0, 'bench')
import convergence as cv
import random_tunnels as rt
from wind_shaper.control.adaptive import is_level
part, nparts = int(sys.argv[1]), int(sys.argv[2])
files = sys.argv[3:]
stored = {}
for f in files:
    for r in json.load(open(f))['cases']:
        if 'flat' in r['methods']:
            stored[r['case']] = r
written = {}
for f in glob.glob('bench/tunnels/written_*/*.yaml'):
    name, effects, targets = cv.load_tunnel_file(f)
    written[name] = (effects, targets)
by_plant = {}
for c, r in stored.items():
    by_plant.setdefault(r['plant'], []).append(r)
out = {}
for i, (pname, rows) in enumerate(sorted(by_plant.items())):
    if i % nparts != part:
        continue
    cv.OWN_TUNNELS.clear()
    if pname.startswith('random '):
        sd, idx = pname.split(':')[0].split()[1].split('-')
        t = rt.draw_tunnels(12, int(sd), 3)[int(idx)]
        cv.OWN_TUNNELS[pname] = (t['effects'], [r['target'] for r in rows])
    elif pname in written:
        cv.OWN_TUNNELS[pname] = written[pname]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            plant = cv.make_plants([pname], Path(tmp))[0]
            kp = plant.setup.geometry.key_points
            on = plant.setup.geometry.fans.enabled
            sim = plant.sim(0)
            levels = [np.asarray(p.U, float) for p in (plant.prior_maps or []) if is_level(p.U, on)]
            for r in rows:
                tv = plant.setup.make_target(r['target']).values(kp)
                zs = r['zeta_star_N2']
                lv = [float(np.mean((sim.true_field(U, kp) - tv) ** 2)) / zs for U in levels]
                out[r['case']] = {'levels': [float(np.max(U)) for U in levels], 'level_ratio': lv,
                                  'k0': float(np.median(np.array(r['methods']['warm+short']['ratio_per_seed'])[:, 0]))}
    except Exception as e:
        print('skip', pname, e, flush=True)
    json.dump(out, open(f'/tmp/s89/lvw_{part}.json', 'w'))
print('done', len(out), flush=True)
