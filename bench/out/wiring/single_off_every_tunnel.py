# Run from the repository root: PYTHONPATH=. python bench/out/wiring/single_off_every_tunnel.py OUT.json [PART PARTS]
"""The wiring check on single-off sweeps (every fan at the middle, each switched off in turn;
1000 samples a sweep) of every bench tunnel of check_every_tunnel.py and draw 2038: as wired
(the two built with a swapped pair among them), and, but for those two, recorded three more
times misrouted as in misrouted_every_tunnel.py (two leads exchanged, three moved round, the
six ring fans' leads one output along; drawn per tunnel, seeded)."""
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


part, parts = (int(sys.argv[2]), int(sys.argv[3])) if len(sys.argv) > 3 else (0, 1)
s = Setup.load()
tunnels = [(n, e) for n, e in cv.UNFAMILIAR.items()]
for f in sorted(glob.glob('bench/tunnels/*/*.yaml')):
    name, eff, tg = cv.load_tunnel_file(f)
    tunnels.append((name, eff))
for d in range(2026, 2039):
    for t in rt.draw_tunnels(12, d, 3):
        tunnels.append((t['name'], t['effects']))
rng = np.random.default_rng(2038)
draws = [(rng.choice(7, 2, replace=False), rng.choice(7, 3, replace=False)) for _ in tunnels]
rows, tally = [], {}
for (name, eff), (pair, three) in list(zip(tunnels, draws))[part::parts]:
    built = any(e['name'] == 'swapped_channels' for e in eff)
    sim = s.make_sim(seed=0, effects=list(effects_from_config(eff)))
    fans = sim.geometry.fans
    n = len(fans.names)
    ring = [i for i, p in enumerate(fans.positions) if np.hypot(*p) > 0.05]
    design = make_design('single-off', fans, s.shaping.u_min, s.shaping.u_max)
    for kind in ('as wired',) + (() if built else ('pair', 'three round', 'ring one along')):
        order = np.arange(n)
        if kind == 'pair':
            order[pair[0]], order[pair[1]] = pair[1], pair[0]
        elif kind == 'three round':
            a, b, c = three
            order[a], order[b], order[c] = b, c, a
        elif kind == 'ring one along':
            order[ring] = np.roll(ring, -1)
        w = check_wiring(from_sim(Misrouted(sim, order), design.commands, n_samples=1000), fans)
        truth = {(fans.names[order[k]], fans.names[k]) for k in range(n) if order[k] != k}
        found = set(w.drives)
        verdict = 'exact' if found == truth else ('none' if not found else 'other')
        label = kind + (' (built swapped)' if built else '')
        tally.setdefault(label, {}).setdefault(verdict, 0)
        tally[label][verdict] += 1
        rows.append({'tunnel': name, 'kind': label, 'truth': sorted(map(list, truth)), 'found': sorted(map(list, found)),
                     'verdict': verdict, 'evidence_sd': w.evidence, 'method': w.method, 'why': w.why})
        print(f"{name[:50]:50s} {label:15s} {verdict:6s} {w.method} {w.evidence:.1f}", flush=True)
json.dump({'tally': tally, 'rows': rows}, open(sys.argv[1], 'w'), indent=1)
print('tunnels', len(tunnels[part::parts]), tally)
