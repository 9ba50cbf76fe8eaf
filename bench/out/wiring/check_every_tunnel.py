# Run from the repository root: PYTHONPATH=. python bench/out/wiring/check_every_tunnel.py OUT.json
"""The wiring check's false alarms: every bench tunnel (the hand-written UNFAMILIAR ones, every
written file, the drawn ones of draws 2026-2037), its designed sweeps (lhs:6+level, seed 0, as
`commission_from_design` records them) checked as wired."""
import sys, glob, json
import numpy as np
sys.path.insert(0, 'bench')
import convergence as cv, random_tunnels as rt
from wind_shaper.experiment.design import make_design
from wind_shaper.workbench.data import from_sim
from wind_shaper.workbench.wiring import check_wiring
from wind_shaper.sim import effects_from_config
from wind_shaper.app import Setup
s = Setup.load()
tunnels = [(n, e) for n, e in cv.UNFAMILIAR.items()]
for f in sorted(glob.glob('bench/tunnels/*/*.yaml')):
    name, eff, tg = cv.load_tunnel_file(f)
    tunnels.append((name, eff))
for d in range(2026, 2038):
    for t in rt.draw_tunnels(12, d, 3):
        tunnels.append((t['name'], t['effects']))
rows = []
for name, eff in tunnels:
    sim = s.make_sim(seed=0, effects=list(effects_from_config(eff)))
    fans = sim.geometry.fans
    design = make_design('lhs:6+level', fans, s.shaping.u_min, s.shaping.u_max, seed=0)
    w = check_wiring(from_sim(sim, design.commands, n_samples=1000), fans)
    rows.append({'tunnel': name, 'drives': [list(p) for p in w.drives], 'rmse_as_wired_N': w.rmse_as_wired,
                 'rmse_rerouted_N': w.rmse_swapped, 'ratio': w.rmse_swapped / w.rmse_as_wired})
    print(f"{name[:60]:60s} {w.drives} {w.rmse_swapped / w.rmse_as_wired:.3f}", flush=True)
json.dump(rows, open(sys.argv[1], 'w'), indent=1)
print('tunnels', len(rows), 'flagged', [(x['tunnel'], x['drives']) for x in rows if x['drives']],
      'lowest ratio of the unflagged %.3f' % min(x['ratio'] for x in rows if not x['drives']))
