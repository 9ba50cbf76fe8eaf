"""FieldEstimate.at: the estimated field at any position of the measured disc, from its GP."""
import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.core.errors import SweepError


@pytest.fixture(scope='module')
def estimate():
    setup = Setup.load()
    sim = setup.make_sim(seed=4)
    U = np.where(setup.geometry.fans.enabled, 0.45, 0.0)
    sim.apply(U)
    est = setup.shaping.make_estimator().estimate(sim.sweep(1000), setup.geometry.key_points)
    return est, sim, U, setup.geometry.sweep_radius


def test_between_the_key_points_it_is_the_gp_and_at_them_the_estimate(estimate):
    est, sim, U, radius = estimate
    mean, std = est.at(est.key_points[:5], radius)
    np.testing.assert_allclose(mean, est.mean[:5], atol=1e-9)
    np.testing.assert_allclose(std, est.std[:5], atol=1e-9)
    rng = np.random.default_rng(1)
    P = rng.uniform(-0.2, 0.2, (50, 2))
    mean, std = est.at(P, radius)
    # as close to the simulator's truth between the key points as at them
    at_keys = np.sqrt(np.mean((est.mean - sim.true_field(U, est.key_points)) ** 2))
    between = np.sqrt(np.mean((mean - sim.true_field(U, P)) ** 2))
    assert between < 1.3 * at_keys, (between, at_keys)
    assert np.all(std > 0)


@pytest.mark.parametrize('points, words', [([[0.0, 0.0], [0.5, 0.0]], 'outside the measured disc'),
                                           ([[np.nan, 0.0]], 'not a finite number'),
                                           ([0.0, 0.1, 0.2], 'pairs')])
def test_a_bad_position_is_named(estimate, points, words):
    est, _, _, radius = estimate
    with pytest.raises(SweepError, match=words):
        est.at(points, radius)
