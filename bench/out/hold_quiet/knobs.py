# ratio per k (true field) for a tunnel/target over seeds for one setting; prints a row
# TUNNEL: file.yaml | plant name ; prefix flat: for the flat start
import sys, tempfile
from pathlib import Path
import os; R = os.environ.get('ROOT', '/work/main'); sys.path.insert(0, R + '/bench'); sys.path.insert(0, R)
import numpy as np
import convergence as c
from wind_shaper.control.loop import ShapingLoop
tfile, tn, seeds, iters = sys.argv[1], sys.argv[2], [int(s) for s in sys.argv[3].split(',')], int(sys.argv[4])
sets = dict(a.split('=') for a in sys.argv[5:])
u0 = 'warm'
if tfile.startswith('flat:'): u0, tfile = 0.5, tfile[5:]
if tfile.endswith('.yaml'):
    name, effects, targets = c.load_tunnel_file(tfile)
    c.OWN_TUNNELS[name] = (effects, [tn])
else:
    name = tfile
plant = c.make_plants([name], Path(tempfile.mkdtemp()))[0]
setup = plant.setup; kp = setup.geometry.key_points
tv = np.asarray(setup.make_target(tn).values(kp), float)
z, Ustar = c.zeta_star(plant, tv)
rows = []; helds = []
for seed in seeds:
    sim = plant.sim(seed)
    rule = setup.shaping.make_rule(method='adaptive', **{k: c._value(v) for k, v in sets.items()})
    loop = ShapingLoop(sim, plant.prior, tv, rule, setup.shaping.make_estimator(plant.prior), u0=u0,
                       n_samples=setup.shaping.samples_per_sweep, sweep_length=setup.shaping.make_sweep_length(),
                       fan_settle_s=setup.shaping.fan_settle_s, model_error=plant.model_error, prior_maps=plant.prior_maps)
    r = []; h = 0
    for i in range(iters + 1):
        rec = loop.iterate(update=i < iters)
        r.append(np.mean((sim.true_field(rec.pwm, kp) - tv) ** 2) / z)
        h += bool(rec.info.get('held'))
    rows.append(r); helds.append(h)
R_ = np.array(rows); med = np.median(R_, axis=0)
lab = os.path.basename(tfile)[:28] + ' ' + tn[:5] + ' ' + ('flat' if u0 == 0.5 else 'warm')
print(f"{lab:40s} {' '.join(sys.argv[5:]) or 'default':18s} med " + ' '.join('%.3f' % x for x in med), '| held', helds, flush=True)
