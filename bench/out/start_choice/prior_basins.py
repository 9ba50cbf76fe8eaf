"""The prior's local optima from many starts for named cases; predicted (ratio to warm) and true ratio.
usage: basins2.py CASES.txt"""
import sys, json, glob, tempfile
from pathlib import Path
import numpy as np
sys.path.insert(0, 'bench')
import convergence as cv
import random_tunnels as rt
from wind_shaper.control.warm_start import warm_start, _polish
from wind_shaper.control.update import CommandBounds
stored = {}
for f in [g for g in glob.glob('/work/main/bench/out/level_top/*.json') if 'screen' not in g and 'without' not in g]:
    for r in json.load(open(f))['cases']:
        stored[r['case']] = r
written = {}
for f in glob.glob('bench/tunnels/written_*/*.yaml'):
    name, effects, targets = cv.load_tunnel_file(f)
    written[name] = (effects, targets)
wanted = [l.strip() for l in open(sys.argv[1]) if l.strip()]
NS = int(sys.argv[2]) if len(sys.argv) > 2 else 24
for c in wanted:
    pname, target = c.rsplit(', ', 1)
    r = stored.get(c)
    flat = shp = None
    if r:
        m = lambda x: np.median(np.array(x), 0)
        shp = m(r['methods']['warm+short']['ratio_per_seed']); flat = m(r['methods']['flat']['ratio_per_seed'])
    cv.OWN_TUNNELS.clear()
    if pname.startswith('random '):
        sd, idx = pname.split(':')[0].split()[1].split('-')
        t = rt.draw_tunnels(12, int(sd), 3)[int(idx)]
        cv.OWN_TUNNELS[pname] = (t['effects'], [target])
    elif pname in written:
        cv.OWN_TUNNELS[pname] = written[pname]
    with tempfile.TemporaryDirectory() as tmp:
        plant = cv.make_plants([pname], Path(tmp))[0]
        kp = plant.setup.geometry.key_points
        tv = plant.setup.make_target(target).values(kp)
        zs, U_star = cv.zeta_star(plant, tv)
        sim = plant.sim(0)
        sh = plant.setup.shaping
        on = plant.setup.geometry.fans.enabled
        bounds = CommandBounds(sh.u_min, sh.u_max)
        model = plant.prior
        ws = warm_start(model, kp, tv, bounds, on, model_error=plant.model_error)
        pm = lambda U: float(np.mean((np.asarray(model(U, kp)) - tv) ** 2))
        tm = lambda U: float(np.mean((sim.true_field(U, kp) - tv) ** 2)) / zs
        rng = np.random.default_rng(1)
        n = len(on)
        starts = [np.full(n, 0.5)] + [rng.uniform(sh.u_min, sh.u_max, n) for _ in range(NS)]
        rows = []
        for s in starts:
            U = _polish(model, kp, tv, bounds, on, bounds.project(s, on))
            U = bounds.project(np.where(on & (U < 0.02), sh.u_min, U), on)
            if np.max(np.abs(U - ws.U)) < 0.05 or any(np.max(np.abs(U - q[0])) < 0.05 for q in rows):
                continue
            rows.append((U, pm(U), tm(U)))
        rows.sort(key=lambda q: q[1])
        p0 = pm(ws.U)
        tag = ''
        if r:
            tag = f"shipped k0/1/2/4/12 {np.round(shp[[0,1,2,4,12]],3)} flat {np.round(flat[[0,1,2,4,12]],3)}"
        print(f'== {c}: {tag}\n   warm pred {p0/zs:.3f}x true {tm(ws.U):.3f} calib_err^2 {plant.model_error**2/zs:.3f}x  U*: pred {pm(U_star)/zs:.3f} true 1  |U*-warm| {np.max(np.abs(U_star-ws.U)):.2f}', flush=True)
        for U, p, tr in rows[:4]:
            print(f'   alt pred {p/zs:.3f}x true {tr:.3f} dist {np.max(np.abs(U-ws.U)):.2f} U {np.round(U,2)}', flush=True)
