"""The fans' footprint length: the longest length scale a field estimate may fit."""
from dataclasses import replace

import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.core.errors import ConfigError
from wind_shaper.estimation import FieldEstimator
from wind_shaper.estimation.turbulent import _length_penalty
from wind_shaper.model import FanJets
from wind_shaper.model.length_scale import footprint_length_scale


def jets(fans, sigma):
    return FanJets(fans, thrust_higher=(0.1, 2.5, 11.0), thrust_lower=(0.05, 2.0, 8.0), sigma=sigma)


@pytest.mark.parametrize('sigma', [0.03, 0.1, 0.35])
def test_a_gaussian_jet_gives_its_own_width(rig, sigma):
    # FanJets' footprint exp(-d^2 / sigma^2) has the autocorrelation exp(-d^2 / (2 sigma^2)):
    # a squared exponential of length sigma. 0.35 m is wider than a third of the first grid's
    # reach (0.6 m): measured there it would look narrower, so the grid is widened.
    assert footprint_length_scale(jets(rig.fans, sigma)) == pytest.approx(sigma, rel=0.01)


def test_the_shipped_prior_gives_its_jets_width(rig):
    prior = Setup.load().load_model()
    measured = footprint_length_scale(prior)
    # the prior is jets plus the central fan's ring and swirl: the jets set the median fan's
    assert measured == pytest.approx(prior.k1.sigma, rel=0.03)


def test_disabled_fans_are_not_measured_and_no_fan_gives_none(rig):
    fans = rig.fans
    assert footprint_length_scale(jets(fans.with_disabled(fans.names), 0.1)) is None

    class Flat:
        """A model with no spatial structure: every Jacobian entry 0."""
        def jacobian(self, U, Z):
            return np.zeros((len(Z), len(U)))
    assert footprint_length_scale(Flat(), fans) is None
    with pytest.raises(ValueError, match='step'):
        footprint_length_scale(jets(fans, 0.1), step=1.0, reach=0.5)


def test_the_estimator_bounds_the_fitted_length_by_the_footprint(rig):
    shaping = Setup.load().shaping
    prior = jets(rig.fans, 0.12)
    soft = shaping.make_estimator(prior)
    assert soft.max_length_scale == pytest.approx(0.12, rel=0.01)
    # the shipped bound is soft: the fit keeps its bounds and pays a prior beyond the length
    assert soft.length_prior == (soft.max_length_scale, 0.1)
    assert soft.fit_bounds['length_scale'] == soft.length_scale_bounds
    hard = replace(soft, max_length_scale_sd=0.0)
    assert hard.length_prior is None
    assert hard.fit_bounds['length_scale'] == (0.05, hard.max_length_scale)
    # no model (a caller that only reads the coverage settings): no bound
    assert shaping.make_estimator().max_length_scale is None
    assert shaping.make_estimator().length_prior is None
    # a number, none, or refused by name
    fixed = replace(shaping, estimator={**shaping.estimator, 'max_length_scale': 0.2})
    assert fixed.make_estimator(prior).max_length_scale == 0.2
    off = replace(shaping, estimator={**shaping.estimator, 'max_length_scale': 'none'})
    assert off.make_estimator(prior).max_length_scale is None
    bad = replace(shaping, estimator={**shaping.estimator, 'max_length_scale': 'jets'})
    with pytest.raises(ConfigError, match='max_length_scale'):
        bad.make_estimator(prior)
    # a hard bound below the lowest length keeps the lowest
    assert FieldEstimator(max_length_scale=0.01).fitted_length_scales == (0.05, 0.05)
    with pytest.raises(ConfigError, match='max_length_scale'):
        FieldEstimator(max_length_scale=-0.1)
    with pytest.raises(ConfigError, match='max_length_scale_sd'):
        FieldEstimator(max_length_scale=0.1, max_length_scale_sd=-1)


def test_the_length_prior_is_zero_up_to_the_length_then_half_normal():
    prior = (0.15, 0.1)
    assert _length_penalty(np.array([np.log(0.1)]), prior) == (0.0, 0.0)
    assert _length_penalty(np.array([np.log(0.3)]), None) == (0.0, 0.0)
    x = np.log(0.15) + 0.2          # two sds above the length
    value, slope = _length_penalty(np.array([x]), prior)
    assert value == pytest.approx(2.0)
    h = 1e-6
    up, down = (_length_penalty(np.array([x + d]), prior)[0] for d in (h, -h))
    numeric = (up - down) / (2 * h)
    assert slope == pytest.approx(numeric, rel=1e-6)


def test_a_sweep_is_fitted_near_the_footprint_length(rig):
    setup = Setup.load()
    sim = setup.make_sim(seed=3)
    sim.apply(np.full(rig.fans.n_fans, 0.5))
    sweep = sim.sweep(600)
    shipped = setup.shaping.make_estimator(jets(rig.fans, 0.12))
    free = replace(shipped, max_length_scale=None).estimate(sweep, rig.key_points)
    soft = shipped.estimate(sweep, rig.key_points)
    hard = replace(shipped, max_length_scale_sd=0.0).estimate(sweep, rig.key_points)
    lengths = [e.gp.params_.length_scale for e in (free, soft, hard)]
    # on its own the likelihood takes a longer length on this sweep; the soft bound pulls it
    # towards the footprint's, the hard one holds it there
    assert lengths[0] > 0.14
    assert 0.12 < lengths[1] < lengths[0] - 0.01
    assert lengths[2] <= 0.12 + 1e-9
    # white model: its fit (fit_hyperparameters) takes the bound as a hard one
    white = replace(shipped, noise_model='white', fit_hyperparameters=True, sample_window_s=0.0)
    assert white.estimate(sweep, rig.key_points).gp.length_scale <= 0.12 + 1e-9
