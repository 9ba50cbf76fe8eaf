"""The tiled turbulent GP (large walls): a calibrated std on force-proportional, gusty noise where
the tiled white GP's is far too small; close to the exact turbulent GP where both can run; the
hyperparameters fitted on a bounded subset, or carried over from an earlier estimate."""
from dataclasses import replace

import numpy as np
import pytest

from wind_shaper.core.errors import ConfigError, SweepError
from wind_shaper.core.geometry import FanArray, TunnelGeometry, rect_key_points
from wind_shaper.core.tunnel import Sweep
from wind_shaper.estimation import (FieldEstimator, LocalGaussianProcessField,
                                    LocalTurbulentGaussianProcessField, TurbulenceParameters,
                                    TurbulentGaussianProcessField)
from wind_shaper.estimation.local_turbulent import fit_subset
from wind_shaper.sim import NoiseModel, SimulatedTunnel

GUSTY = NoiseModel(relative=0.06, absolute=0.02, correlation_time=0.15, correlated_fraction=0.7)
LOCAL = FieldEstimator(method='local')


def fan_wall(n_side=6, n_key=400, pitch=0.08) -> TunnelGeometry:
    """An n x n wall of 8 cm fans, key points on a square grid over it (as bench/scale.py)."""
    half = pitch * n_side / 2
    k = int(round(np.sqrt(n_key)))
    return TunnelGeometry(FanArray.grid(n_side, n_side, pitch), rect_key_points(half, half, k, k),
                          wall_radius=half + 0.1, sweep_radius=float(np.sqrt(2) * half) + 0.01,
                          extra={'wall_shape': 'square'})


def sweep_at(geo, seed, n_samples=1500):
    """A sweep at random commands (each fan uniform in 0.3..0.65) and the true field at the key
    points [N]."""
    sim = SimulatedTunnel(geo, seed=seed, noise=GUSTY)
    sim.apply(np.random.default_rng(seed).uniform(0.3, 0.65, geo.fans.n_fans))
    return sim.sweep(n_samples), sim.true_field(sim.pwm, geo.key_points)


def z_scores(geo, estimator, seeds=(0, 1, 2)):
    out = []
    for seed in seeds:
        sweep, truth = sweep_at(geo, seed)
        est = estimator.estimate(sweep, geo.key_points)
        out.append((est.mean - truth) / est.std)
    return np.concatenate(out)


def test_tiled_std_is_calibrated_on_gusty_force_proportional_noise_where_the_white_one_is_not():
    geo = fan_wall()
    z_new = z_scores(geo, LOCAL)
    z_old = z_scores(geo, replace(LOCAL, noise_model='white'))
    rms_new, rms_old = np.sqrt(np.mean(z_new ** 2)), np.sqrt(np.mean(z_old ** 2))
    # three sweeps of ~400 correlated key points: the band allows their spread around 1
    z_exact = z_scores(geo, replace(LOCAL, method='exact'))
    rms_exact = np.sqrt(np.mean(z_exact ** 2))
    # three sweeps of ~400 correlated key points: the band allows their spread around 1 (and
    # the tiles' std, from fewer samples, is a little larger than the exact GP's: 0.8-0.9 here)
    assert 0.7 <= rms_new <= 1.25, rms_new
    assert np.mean(np.abs(z_new) > 2) <= 0.1
    assert abs(np.log(rms_new / rms_exact)) < 0.2, (rms_new, rms_exact)
    assert rms_old > 2.0, rms_old             # the white noise_std is far below the turbulence


def test_the_default_estimator_tiles_with_the_turbulent_model_above_max_exact():
    assert isinstance(FieldEstimator().make_gp(5000), LocalTurbulentGaussianProcessField)
    assert type(FieldEstimator().make_gp(500)) is TurbulentGaussianProcessField
    assert type(FieldEstimator(noise_model='white').make_gp(5000)) is LocalGaussianProcessField
    gp = FieldEstimator(local_block=0.3, local_halo=0.1, max_fit_samples=900).make_gp(5000)
    assert (gp.tile, gp.halo, gp.max_fit_samples) == (0.3, 0.1, 900)


def test_tiles_agree_with_the_exact_turbulent_gp_on_a_small_area(rig):
    sweep, _ = sweep_at(rig, seed=3, n_samples=1000)
    exact = FieldEstimator(method='exact').estimate(sweep, rig.key_points)
    # the same hyperparameters (carried over from the exact fit), solved tile by tile
    tiled = LOCAL.estimate(sweep, rig.key_points, reuse=exact)
    assert isinstance(tiled.gp, LocalTurbulentGaussianProcessField)
    assert tiled.gp.params_ == exact.gp.params_ and tiled.gp.evaluations_ == 0
    diff = (tiled.mean - exact.mean) / exact.std
    # a tile sees the samples within 15 cm: it misses little, so the means differ by a small
    # fraction of the std, and the std can only grow (less data), by a few per cent
    assert np.sqrt(np.mean(diff ** 2)) < 0.2 and np.max(np.abs(diff)) < 0.8
    ratio = tiled.std / exact.std
    assert np.all(ratio > 0.999) and np.all(ratio < 1.1), (ratio.min(), ratio.max())
    # with a halo twice as wide the tiles see (nearly) what the exact GP sees
    wide = replace(LOCAL, local_halo=0.3).estimate(sweep, rig.key_points, reuse=exact)
    assert np.max(np.abs(wide.mean - exact.mean) / exact.std) < 0.2
    assert np.allclose(wide.std, exact.std, rtol=0.01)


def test_the_fit_on_all_samples_and_on_a_bounded_subset_agree(rig):
    sweep, _ = sweep_at(rig, seed=5, n_samples=1000)
    sub = FieldEstimator(method='exact').estimate(sweep, rig.key_points).gp
    X, y, t = sub.X_, sub.y_, sub.t_
    full = LocalTurbulentGaussianProcessField(sub.start, block=sub.block).fit(X, y, t)
    part = LocalTurbulentGaussianProcessField(sub.start, block=sub.block,
                                              max_fit_samples=len(y) // 2).fit(X, y, t)
    assert full.fitted_ and part.fitted_ and full.fit_samples_ == len(y)
    assert 0 < part.fit_samples_ <= len(y) // 2
    assert full.params_ == sub.params_              # all samples: the exact GP's fit exactly
    noise = [np.sqrt(p.absolute ** 2 + (np.mean(y) * p.relative) ** 2) for p in (full.params_, part.params_)]
    assert noise[1] == pytest.approx(noise[0], rel=0.3)
    assert part.params_.length_scale == pytest.approx(full.params_.length_scale, rel=0.4)


def test_fit_subset_takes_evenly_spread_runs_of_consecutive_samples():
    assert np.array_equal(fit_subset(500, 80, 2000), np.arange(500))
    idx = fit_subset(10_000, 80, 2000)
    runs = idx.reshape(-1, 80)
    assert len(idx) == 2000 and len(runs) == 25
    assert np.all(np.diff(runs, axis=1) == 1)             # each run consecutive
    assert np.all(np.diff(runs[:, 0]) >= 80)              # no overlap, in time order
    assert runs[0, 0] == 0 and runs[-1, -1] == 9_999      # from the sweep's start to its end
    assert len(fit_subset(1000, 80, 100)) == 80           # one run when only one fits


def test_an_interim_tiled_estimate_reuses_the_fitted_values(rig):
    sweep, _ = sweep_at(rig, seed=4, n_samples=1000)
    first = LOCAL.estimate(Sweep(sweep.positions[:700], sweep.forces[:700], sweep.times[:700], sweep.pwm),
                           rig.key_points)
    assert first.gp.fitted_ and first.gp.evaluations_ > 0
    again = LOCAL.estimate(sweep, rig.key_points, reuse=first)
    assert again.gp.params_ == first.gp.params_ and again.gp.evaluations_ == 0 and again.gp.reused_
    # carried on once more, and over to the exact GP (the same model)
    third = FieldEstimator(method='exact').estimate(sweep, rig.key_points, reuse=again)
    assert third.gp.params_ == first.gp.params_ and not third.gp.fitted_
    # a white estimate holds no turbulence fit: the tiled GP fits its own
    white = replace(LOCAL, noise_model='white').estimate(sweep, rig.key_points)
    assert LOCAL.estimate(sweep, rig.key_points, reuse=white).gp.fitted_


def test_points_far_from_every_sample_get_the_prior_and_the_query_serves_the_std(rig):
    sweep, _ = sweep_at(rig, seed=6, n_samples=1000)
    est = LOCAL.estimate(sweep, rig.key_points)
    gp = est.gp
    mean, std = gp.predict(np.array([[3.0, 3.0], [0.0, 0.0]]), return_std=True)
    assert mean[0] == gp.mean_ and std[0] == gp.params_.signal_std
    assert std[1] < 0.2 * gp.params_.signal_std
    force, s = est.at(rig.key_points[:10], radius=1.0)
    assert np.allclose(force, est.mean[:10]) and np.allclose(s, est.std[:10])
    assert len(gp.predict(np.empty((0, 2)))) == 0
    assert np.isfinite(gp.log_marginal_likelihood())


@pytest.mark.parametrize('kwargs,match', [
    ({'tile': 0.0}, 'tile'),
    ({'halo': -0.1}, 'halo'),
    ({'max_fit_samples': 30}, 'max_fit_samples'),
    ({'block': 5}, 'block'),
])
def test_bad_tiled_settings_are_refused_by_name(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        LocalTurbulentGaussianProcessField(**kwargs)


def test_the_estimator_refuses_bad_tile_settings_when_built():
    with pytest.raises(ConfigError, match='tile'):
        FieldEstimator(local_block=0.0)
    with pytest.raises(ConfigError, match='max_fit_samples'):
        FieldEstimator(max_fit_samples=10)


def test_an_unfitted_tiled_gp_says_so():
    gp = LocalTurbulentGaussianProcessField(TurbulenceParameters())
    with pytest.raises(SweepError, match='not fitted'):
        gp.predict(np.zeros((1, 2)))
    with pytest.raises(SweepError, match='not fitted'):
        gp.log_marginal_likelihood()
