"""GET_CLOSEST and the GP field estimate."""
import numpy as np
import pytest

from wind_shaper.core.errors import SweepError
from wind_shaper.estimation.field import (FieldEstimator, GaussianProcessField, closest_samples,
                                    get_closest)
from wind_shaper.core.tunnel import Sweep


def smooth_field(P):
    x, y = P[:, 0], P[:, 1]
    return 3.0 + 1.5 * np.exp(-((x - 0.1) ** 2 + (y + 0.05) ** 2) / 0.03) + 4.0 * (x ** 2 + y ** 2)


def random_sweep(rng, n=1000, radius=0.44, noise=0.0):
    r = radius * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    P = np.column_stack([r * np.cos(a), r * np.sin(a)])
    F = smooth_field(P) + noise * rng.standard_normal(n)
    return Sweep(P, F, np.arange(n) * 0.02, np.full(7, 0.5))


def test_get_closest_picks_the_nearest_sample():
    samples = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    keys = np.array([[0.9, 0.1], [0.1, 0.1], [0.2, 0.7]])
    assert get_closest(samples, keys).tolist() == [1, 0, 2]


def test_closest_samples_drops_repeats_and_nan(rng):
    P = np.array([[0.0, 0.0], [np.nan, 0.0], [0.5, 0.5]])
    sweep = Sweep(P, np.array([1.0, 2.0, np.nan]), np.zeros(3), np.zeros(7))
    sub = closest_samples(sweep, np.array([[0.01, 0.0], [0.02, 0.0]]))
    assert len(sub.forces) == 1 and sub.forces[0] == 1.0


def test_few_key_points_bring_their_nearest_few_samples_many_bring_one(rng):
    P = rng.uniform(-0.3, 0.3, (2000, 2))
    sweep = Sweep(P, rng.normal(size=2000), np.arange(2000) / 50.0, np.zeros(7))
    few = rng.uniform(-0.25, 0.25, (40, 2))
    one = closest_samples(sweep, few)
    more = closest_samples(sweep, few, min_picked=300)
    assert len(one.forces) <= 40 and 250 <= len(more.forces) <= 320   # ceil(300 / 40) = 8 each
    np.testing.assert_array_equal(one.key_distance, more.key_distance)   # coverage unchanged
    many = rng.uniform(-0.25, 0.25, (400, 2))
    np.testing.assert_array_equal(closest_samples(sweep, many).forces,
                                  closest_samples(sweep, many, min_picked=300).forces)


def test_gp_recovers_a_known_field_within_tolerance(rig, rng):
    sweep = random_sweep(rng, noise=0.02)
    est = FieldEstimator(length_scale=0.10, noise_std=0.05).estimate(sweep, rig.key_points)
    truth = smooth_field(rig.key_points)
    rmse = np.sqrt(np.mean((est.mean - truth) ** 2))
    assert rmse < 0.08, rmse  # field spans about 3..5.5 N
    # the reported uncertainty is of the right size: most errors within 3 std
    assert np.mean(np.abs(est.mean - truth) <= 3 * est.std + 0.02) > 0.9


def test_gp_interpolates_noise_free_data_and_std_grows_away_from_data():
    X = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]])
    y = np.array([1.0, 2.0, 3.0])
    gp = GaussianProcessField(length_scale=0.1, noise_std=0.0).fit(X, y)
    mean, std = gp.predict(X, return_std=True)
    np.testing.assert_allclose(mean, y, atol=1e-5)
    _, far_std = gp.predict(np.array([[1.0, 1.0]]), return_std=True)
    assert far_std[0] > 10 * std.max()


@pytest.mark.fault
def test_gp_survives_duplicate_positions(fault_row):
    X = np.zeros((10, 2))
    y = np.linspace(1, 2, 10)
    gp = GaussianProcessField(noise_std=0.0).fit(X, y)
    assert np.isfinite(gp.predict(np.array([[0.0, 0.0]]))).all()
    fault_row('duplicate sample positions (ill-conditioned GP)',
              'estimate stays finite and correct', True)


def test_estimator_refuses_thin_or_partial_sweeps(rig, rng):
    with pytest.raises(SweepError, match='usable samples'):
        FieldEstimator(min_samples=50).estimate(random_sweep(rng, n=20), rig.key_points)
    half = random_sweep(rng)
    keep = half.positions[:, 0] > 0
    half = Sweep(half.positions[keep], half.forces[keep], half.times[keep], half.pwm)
    with pytest.raises(SweepError, match='missed .* key points'):
        FieldEstimator().estimate(half, rig.key_points)


def test_gp_rejects_non_finite_and_too_few():
    with pytest.raises(SweepError, match='NaN'):
        GaussianProcessField().fit(np.array([[0, 0], [1, 1], [2, 2.0]]), np.array([1, np.nan, 2]))
    with pytest.raises(SweepError, match='at least 3'):
        GaussianProcessField().fit(np.array([[0, 0.0]]), np.array([1.0]))
