"""The wiring check on square walls: side, pitch [m], designed sweeps (lhs:N+level) and samples per
sweep from the command line (0 sweeps: the single-off design); two seeds; wired as configured, one exchange, three leads moved round,
the first row one output along. Run from the repository root:
  python bench/out/wiring/walls.py 6 0.1 10 1500"""
import sys, time, numpy as np
sys.path.insert(0, 'test/unit/workbench')
from dataclasses import replace
from wind_shaper.core.geometry import FanArray, TunnelGeometry, rect_key_points
from wind_shaper.sim import SimulatedTunnel
from wind_shaper.experiment.design import make_design
from wind_shaper.workbench.data import from_sim
from wind_shaper.workbench.wiring import check_wiring
from test_wiring import _Miswired, _routing
side = int(sys.argv[1]); pitch = float(sys.argv[2]); nsweep = int(sys.argv[3]); ns = int(sys.argv[4])
fans = FanArray.grid(side, side, pitch)
half = pitch * side / 2
geometry = TunnelGeometry(fans, rect_key_points(half, half, 12, 12), wall_radius=half + 0.1,
                          sweep_radius=float(np.sqrt(2) * half) + 0.01, extra={'wall_shape': 'square'})
names = fans.names
cases = [(), ((names[0], names[side + 1]), (names[side + 1], names[0])),
         ((names[1], names[2]), (names[2], names[2 * side + 1]), (names[2 * side + 1], names[1])),
         tuple((names[k], names[(k + 1) % side]) for k in range(side))]   # first row one along
for seed in (0, 1):
    sim = SimulatedTunnel(geometry, seed=seed)
    design = make_design(f"lhs:{nsweep}+level" if nsweep else "single-off", fans, 0.0, 0.65, seed=seed)
    for drives in cases:
        tunnel = _Miswired(sim, _routing(fans, drives)) if drives else sim
        data = from_sim(tunnel, design.commands, n_samples=ns)
        t0 = time.process_time()
        v = check_wiring(data, fans)
        dt = time.process_time() - t0
        ok = set(v.drives) == set(drives)
        print(f'seed {seed} moved {len(drives)}: named {len(v.drives)} exact {ok} rmse {v.rmse_as_wired:.3f} -> {v.rmse_swapped:.3f} {v.method} {v.evidence:.1f} ({dt:.2f} s) {v.why}', flush=True)
