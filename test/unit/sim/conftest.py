"""Fixtures for the simulator tests: the paper rig, its default (lopsided) tunnel, and a
perfect, noise-free tunnel where the documented laws hold exactly."""
import numpy as np
import pytest

from wind_shaper.core.geometry import TunnelGeometry
from wind_shaper.sim import Imperfections, NoiseModel, SimulatedTunnel


@pytest.fixture(scope='session')
def rig():
    return TunnelGeometry.paper_rig()


@pytest.fixture
def tunnel(rig):
    return SimulatedTunnel(rig)


@pytest.fixture
def perfect(rig):
    """No build imperfections, no noise."""
    return SimulatedTunnel(rig, imperfections=Imperfections.none(rig.fans.n_fans),
                           noise=NoiseModel.zero())


@pytest.fixture(scope='session')
def lone(rig):
    """lone(name, u=0.5): a PWM vector with only fan ``name`` at ``u``."""
    def make(name, u=0.5):
        pwm = np.zeros(rig.fans.n_fans)
        pwm[rig.fans.index(name)] = u
        return pwm
    return make
