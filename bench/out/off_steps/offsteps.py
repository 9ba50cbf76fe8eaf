# how do steps that switch running fans off fare? shipped default, draws given, seeds, k<=K
import sys, os, tempfile, json
from pathlib import Path
R = os.environ.get('ROOT', os.getcwd()); sys.path.insert(0, R + '/bench'); sys.path.insert(0, R)
import numpy as np
import convergence as c, random_tunnels as rt
from wind_shaper.control.loop import ShapingLoop
draw, seeds, K, out = int(sys.argv[1]), [int(s) for s in sys.argv[2].split(',')], int(sys.argv[3]), sys.argv[4]
sets = json.loads(os.environ.get('SETS', '{}'))
rows = []
for t in rt.draw_tunnels(12, draw, 3):
    name = t['name']; c.OWN_TUNNELS[name] = (t['effects'], ['uniform', 'parabolic', 'gaussian@LM1'])
    plant = c.make_plants([name], Path(tempfile.mkdtemp()))[0]
    setup = plant.setup; kp = setup.geometry.key_points
    for target_name in ('uniform', 'parabolic', 'gaussian@LM1'):
        tv = np.asarray(setup.make_target(target_name).values(kp), float)
        z, _ = c.zeta_star(plant, tv)
        for seed in seeds:
            sim = plant.sim(seed)
            rule = setup.shaping.make_rule(method='adaptive', **sets)
            loop = ShapingLoop(sim, plant.prior, tv, rule, setup.shaping.make_estimator(plant.prior), u0='warm',
                               n_samples=setup.shaping.samples_per_sweep, sweep_length=setup.shaping.make_sweep_length(),
                               fan_settle_s=setup.shaping.fan_settle_s, model_error=plant.model_error, prior_maps=plant.prior_maps)
            prev = None
            for k in range(K + 1):
                rec = loop.iterate(update=k < K)
                true = float(np.mean((sim.true_field(rec.pwm, kp) - tv) ** 2)) / z
                if prev is not None:
                    p = prev
                    rows.append(dict(case=name + ', ' + target_name, seed=seed, k=k, base_true=p['base_true'], true=true,
                                     pred=p['pred'] / z, base_meas=p['base_meas'] / z, off=p['off'], on_=p['on_'], move=p['move'], imp_noise=p['imp_noise']))
                if rec.next_pwm is not None:
                    info = rec.info
                    b = info.get('base_k')
                    Ub = np.asarray(rec.pwm, float)  # approx: base is usually this map
                    Un = np.asarray(rec.next_pwm, float)
                    # base's commands: the map the step was taken from
                    hist = loop.history if hasattr(loop, 'history') else None
                    off = int(np.sum((Ub > 0.02) & (Un <= 1e-9)))
                    on_ = int(np.sum((Ub <= 1e-9) & (Un > 0.02)))
                    prev = dict(base_true=true, pred=info.get('predicted_error', np.nan), base_meas=info.get('base_error', np.nan),
                                off=off, on_=on_, move=float(np.max(np.abs(Un - Ub))),
                                imp_noise=info.get('predicted_improvement', 0) / max(info.get('estimate_noise', 1e-12), 1e-12))
    print(name, len(rows), flush=True)
json.dump(rows, open(out, 'w'))
