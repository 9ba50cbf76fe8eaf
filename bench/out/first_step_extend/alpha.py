"""Per case: how far along the first step the tunnel's optimum lies.
alpha = <U*-U0, U1-U0>/|U1-U0|^2 (enabled fans), cos = angle between U1-U0 and U*-U0,
and the same for the second step from the base. usage: alpha.py CASES.txt OUT.json SEEDS"""
import sys, json, glob, tempfile  # run from the repository's root
from pathlib import Path
import numpy as np
sys.path.insert(0, 'bench')
import convergence as cv
import random_tunnels as rt
cases_file, out, seeds = sys.argv[1], sys.argv[2], int(sys.argv[3])
stored = {}
for f in [g for g in glob.glob('/work/main/bench/out/level_top/*.json') if 'screen' not in g and 'without' not in g] + ['/work/main/bench/out/twelfth/written_2026-12-04e.json', '/work/main/bench/out/eleventh/written_2026-12-04d.json', '/work/main/bench/out/draw_2037/random_tunnels_2037.json', '/work/main/bench/out/draw_2038/random_tunnels_2038.json', '/work/main/bench/out/thirteenth/written_2026-12-04f.json']:
    for r in json.load(open(f))['cases']:
        stored[r['case']] = r
written = {}
for f in glob.glob('bench/tunnels/written_*/*.yaml'):
    name, effects, targets = cv.load_tunnel_file(f)
    written[name] = (effects, targets)
wanted = [l.strip() for l in open(cases_file) if l.strip()]
cfg = {**cv.METHODS['warm+short'], 'rule': dict(cv.METHODS['warm+short']['rule'])}
res = {}
for c in wanted:
    r = stored[c]; pname = r['plant']
    cv.OWN_TUNNELS.clear()
    if pname.startswith('random '):
        sd, idx = pname.split(':')[0].split()[1].split('-')
        t = rt.draw_tunnels(12, int(sd), 3)[int(idx)]
        cv.OWN_TUNNELS[pname] = (t['effects'], [r['target']])
    elif pname in written:
        cv.OWN_TUNNELS[pname] = written[pname]
    with tempfile.TemporaryDirectory() as tmp:
        plant = cv.make_plants([pname], Path(tmp))[0]
        kp = plant.setup.geometry.key_points
        on = plant.setup.geometry.fans.enabled
        tv = plant.setup.make_target(r['target']).values(kp)
        zs, Us = cv.zeta_star(plant, tv)
        rows = []
        for s in range(seeds):
            sim = plant.sim(s)
            loop = cv.make_loop(plant, tv, cfg, cv._TimedTunnel(sim), short=True)
            U, R = [], []
            for i in range(3):
                rec = loop.iterate(update=i < 2)
                U.append(np.asarray(rec.pwm, float)[on]); R.append(float(np.mean((sim.true_field(rec.pwm, kp) - tv) ** 2)) / zs)
            u0, u1, u2, us = U[0], U[1], U[2], np.asarray(Us, float)[on]
            d1, g = u1 - u0, us - u0
            a1 = float(d1 @ g / max(d1 @ d1, 1e-12)); c1 = float(d1 @ g / max(np.linalg.norm(d1) * np.linalg.norm(g), 1e-12))
            # second step from u1
            d2, g2 = u2 - u1, us - u1
            a2 = float(d2 @ g2 / max(d2 @ d2, 1e-12)); c2 = float(d2 @ g2 / max(np.linalg.norm(d2) * np.linalg.norm(g2), 1e-12))
            rows.append(dict(R=R, a1=a1, c1=c1, a2=a2, c2=c2, n1=float(np.abs(d1).max()), gap=float(np.abs(g).max())))
        res[c] = rows
        a1 = np.median([x['a1'] for x in rows]); c1 = np.median([x['c1'] for x in rows]); a2 = np.median([x['a2'] for x in rows])
        print(f"{c[:58]:58s} R {np.round(np.median([x['R'] for x in rows],0),3)} a1 {a1:5.2f} cos1 {c1:5.2f} a2 {a2:5.2f} step1 {np.median([x['n1'] for x in rows]):.2f} gap {np.median([x['gap'] for x in rows]):.2f}", flush=True)
        json.dump(res, open(out, 'w'))
