"""Shared fixtures: geometry of the paper's rig and small synthetic data."""
import numpy as np
import pytest

from wind_shaper.core.geometry import TunnelGeometry


@pytest.fixture
def rig():
    return TunnelGeometry.paper_rig()


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
