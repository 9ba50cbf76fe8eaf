"""Bags for the bag tests, generated in tmp_path from the simulator (nothing committed)."""
import numpy as np
import pytest

from wind_shaper.core.geometry import TunnelGeometry
from wind_shaper.sim import SimulatedTunnel


@pytest.fixture(scope='module')
def sim_sweeps():
    """Two short simulated sweeps at 100 Hz (pose rate) with different commands."""
    geometry = TunnelGeometry.paper_rig()
    sim = SimulatedTunnel(geometry, seed=7, sample_rate_hz=100.0)
    sweeps = []
    for level in (0.35, 0.55):
        sim.apply(np.full(geometry.fans.n_fans, level))
        sweeps.append(sim.sweep(150))
    return sweeps
