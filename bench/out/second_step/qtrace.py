import sys, tempfile
from pathlib import Path
import os; R = os.environ.get('ROOT', '/work/main'); sys.path.insert(0, R + '/bench'); sys.path.insert(0, R)
import numpy as np
import convergence as c
from wind_shaper.control.loop import ShapingLoop
tfile, tn, seeds, iters = sys.argv[1], sys.argv[2], [int(s) for s in sys.argv[3].split(',')], int(sys.argv[4])
if tfile.endswith('.yaml'):
    name, effects, targets = c.load_tunnel_file(tfile); c.OWN_TUNNELS[name] = (effects, [tn])
else:
    name = tfile
plant = c.make_plants([name], Path(tempfile.mkdtemp()))[0]
setup = plant.setup; kp = setup.geometry.key_points
tv = np.asarray(setup.make_target(tn).values(kp), float)
z, Ustar = c.zeta_star(plant, tv)
for seed in seeds:
    sim = plant.sim(seed)
    rule = setup.shaping.make_rule(method='adaptive')
    loop = ShapingLoop(sim, plant.prior, tv, rule, setup.shaping.make_estimator(plant.prior), u0='warm',
                       n_samples=setup.shaping.samples_per_sweep, sweep_length=setup.shaping.make_sweep_length(),
                       fan_settle_s=setup.shaping.fan_settle_s, model_error=plant.model_error, prior_maps=plant.prior_maps)
    out = []
    for i in range(iters + 1):
        rec = loop.iterate(update=i < iters)
        r = np.mean((sim.true_field(rec.pwm, kp) - tv) ** 2) / z
        q = rec.info.get('_q')
        out.append(f'k{i} {r:.3f}' + (f' q {q[0]/max(q[1],1e-9):.2f} (miss {q[0]:.3f} chg {q[1]:.3f} act {q[2]:.3f})' if q else '') + (f" rho {rec.info.get('rho'):.2f}" if rec.info.get('rho') is not None else ''))
    print(os.path.basename(tfile)[:24], tn[:5], 'seed', seed, ' | '.join(out), flush=True)
