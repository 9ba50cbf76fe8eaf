"""The residual described in physical words: a tilt with its direction, and what the residual at
its peak follows from sweep to sweep (the CW/CCW balance, or no command at all)."""
import numpy as np
import pytest

from wind_shaper.core.geometry import TunnelGeometry
from wind_shaper.model import Background
from wind_shaper.workbench.data import FitData
from wind_shaper.workbench.residuals import analyse_residuals


@pytest.fixture(scope='module')
def rig():
    return TunnelGeometry.paper_rig()


def _data(rig, residual, n_sweeps=10, per_sweep=400, seed=0):
    """Sweeps at random commands over the disc; y = residual(U, Z) + 0.02 N noise."""
    rng = np.random.default_rng(seed)
    U, Z, s = [], [], []
    for k in range(n_sweeps):
        u = rng.uniform(0.1, 0.9, rig.fans.n_fans)
        r = 0.28 * np.sqrt(rng.uniform(0, 1, per_sweep))
        a = rng.uniform(-np.pi, np.pi, per_sweep)
        U.append(np.tile(u, (per_sweep, 1)))
        Z.append(np.column_stack([r * np.cos(a), r * np.sin(a)]))
        s.append(np.full(per_sweep, k))
    U, Z, s = np.vstack(U), np.vstack(Z), np.concatenate(s)
    y = residual(U, Z) + 0.02 * rng.standard_normal(len(s))
    return FitData(U, Z, y, s, np.ones(len(s), int))


def test_a_plane_is_called_a_tilt_with_its_direction(rig):
    zero = Background(rig.fans, force=0.0)
    data = _data(rig, lambda U, Z: 2.0 * (Z[:, 0] * np.cos(2.0) + Z[:, 1] * np.sin(2.0)))
    a = analyse_residuals(zero, data, rig)
    direction, per_10cm, share = a.tilt()
    assert abs(direction - np.degrees(2.0)) < 5 and per_10cm == pytest.approx(0.2, rel=0.15)
    assert share > 0.9 and any('tilts across the tunnel' in line for line in a.describe())


def test_a_local_residual_that_follows_the_cw_ccw_balance_is_said_to(rig):
    zero = Background(rig.fans, force=0.0)
    s = rig.fans.spin_sign

    def swirl_like(U, Z):
        T = U ** 2
        b = T @ s / T.sum(axis=1)
        return 3.0 * b * np.exp(-np.sum((Z - [0.1, 0.1]) ** 2, axis=1) / 0.06 ** 2)
    a = analyse_residuals(zero, _data(rig, swirl_like), rig)
    assert 'CW/CCW balance' in a.peak_follows


def test_a_residual_that_ignores_the_commands_is_said_to(rig):
    zero = Background(rig.fans, force=0.0)
    patch = lambda U, Z: 0.5 * np.exp(-np.sum((Z - [-0.1, 0.05]) ** 2, axis=1) / 0.06 ** 2)  # noqa: E731
    a = analyse_residuals(zero, _data(rig, patch), rig)
    assert a.peak_follows.startswith('no command: it stays about +0.')
    assert a.tilt()[2] < 0.5 and not any('tilts' in line for line in a.describe())
