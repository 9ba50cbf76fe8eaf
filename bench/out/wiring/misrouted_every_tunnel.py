# Run from the repository root: PYTHONPATH=. python bench/out/wiring/misrouted_every_tunnel.py OUT.json
"""The wiring check's finds: every bench tunnel of check_every_tunnel.py (the two built
miswired left out), its designed sweeps (lhs:6+level, seed 0) recorded three more times with
the command channels misrouted, drawn per tunnel (seeded): two leads exchanged, three moved
round, and the six ring fans' leads one output along (a connector block plugged one pin over)."""
import sys, glob, json
from dataclasses import replace
import numpy as np
sys.path.insert(0, 'bench')
import convergence as cv, random_tunnels as rt
from wind_shaper.experiment.design import make_design
from wind_shaper.workbench.data import from_sim
from wind_shaper.workbench.wiring import check_wiring
from wind_shaper.sim import effects_from_config
from wind_shaper.app import Setup


class Misrouted:
    """Fan k's motor runs the command sent for fan order[k]; sweeps record the commands sent."""

    def __init__(self, tunnel, order):
        self.tunnel, self.order, self.geometry = tunnel, np.asarray(order), tunnel.geometry

    def apply(self, U):
        self.sent = np.array(U, float)
        self.tunnel.apply(self.sent[self.order])

    def sweep(self, n):
        return replace(self.tunnel.sweep(n), pwm=self.sent.copy())


s = Setup.load()
tunnels = [(n, e) for n, e in cv.UNFAMILIAR.items()]
for f in sorted(glob.glob('bench/tunnels/*/*.yaml')):
    name, eff, tg = cv.load_tunnel_file(f)
    if not any(e['name'] == 'swapped_channels' for e in eff):
        tunnels.append((name, eff))
for d in range(2026, 2038):
    for t in rt.draw_tunnels(12, d, 3):
        tunnels.append((t['name'], t['effects']))
rng = np.random.default_rng(2037)
rows, tally = [], {}
for name, eff in tunnels:
    sim = s.make_sim(seed=0, effects=list(effects_from_config(eff)))
    fans = sim.geometry.fans
    ring = [i for i, p in enumerate(fans.positions) if np.hypot(*p) > 0.05]
    design = make_design('lhs:6+level', fans, s.shaping.u_min, s.shaping.u_max, seed=0)
    n = len(fans.names)
    for kind in ('pair', 'three round', 'ring one along'):
        order = np.arange(n)
        if kind == 'pair':
            a, b = rng.choice(n, 2, replace=False)
            order[a], order[b] = b, a
        elif kind == 'three round':
            a, b, c = rng.choice(n, 3, replace=False)
            order[a], order[b], order[c] = b, c, a
        else:
            order[ring] = np.roll(ring, -1)
        w = check_wiring(from_sim(Misrouted(sim, order), design.commands, n_samples=1000), fans)
        truth = {(fans.names[order[k]], fans.names[k]) for k in range(n) if order[k] != k}
        found = set(w.drives)
        verdict = 'exact' if found == truth else ('none' if not found else 'other')
        tally.setdefault(kind, {}).setdefault(verdict, 0)
        tally[kind][verdict] += 1
        rows.append({'tunnel': name, 'kind': kind, 'truth': sorted(map(list, truth)), 'found': sorted(map(list, found)),
                     'verdict': verdict, 'ratio': w.rmse_swapped / w.rmse_as_wired})
        print(f"{name[:50]:50s} {kind:15s} {verdict:6s} {w.rmse_swapped / w.rmse_as_wired:.3f}", flush=True)
json.dump({'tally': tally, 'rows': rows}, open(sys.argv[1], 'w'), indent=1)
print('tunnels', len(tunnels), tally)
