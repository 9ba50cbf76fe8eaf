"""The base plant: protocol, determinism, sweeps, noise, lopsidedness, the central-fan ring,
plate averaging, scaling code paths, reachability and config."""
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.optimize import least_squares

from wind_shaper.core.errors import ConfigError
from wind_shaper.core.geometry import FanArray, TunnelGeometry, rect_key_points
from wind_shaper.core.tunnel import Sweep, Tunnel
from wind_shaper.sim import (CommandError, Imperfections, NoiseModel, RandomWalkPath,
                             SimulatedTunnel, TourPath)
from wind_shaper.sim.physics import FlatTop, JetGroup, _block

CONFIG = Path(__file__).resolve().parents[3] / 'config' / 'sim.yaml'


def ring_lopsidedness(tunnel, pwm, points, r_max=0.3):
    """Largest max/min - 1 of the true force over lattice rings (same radius, >= 4 points)."""
    r = np.round(np.hypot(*points.T), 6)
    f = tunnel.true_field(pwm, points)
    return max(f[r == rad].max() / f[r == rad].min() - 1
               for rad in np.unique(r[r <= r_max]) if np.sum(r == rad) >= 4)


def c3_asymmetry(tunnel, pwm, points):
    """Largest relative change of the true force under the rig's 120-degree symmetry."""
    f = tunnel.true_field(pwm, points)
    worst = 0.0
    for k in (1, 2):
        a = 2 * np.pi * k / 3
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        worst = max(worst, np.max(np.abs(tunnel.true_field(pwm, points @ rot.T) / f - 1)))
    return worst


# -- protocol and commands -----------------------------------------------------------------------
def test_satisfies_tunnel_protocol(tunnel):
    assert isinstance(tunnel, Tunnel)


def test_apply_clips_and_holds_disabled_fans_at_zero(rig):
    sim = SimulatedTunnel(rig.with_disabled(['CM']))
    applied = sim.apply([1.4, -0.2, 0.5, 0.5, 0.5, 0.5, 0.9])
    assert applied[0] == 1.0 and applied[1] == 0.0 and applied[-1] == 0.0
    assert np.array_equal(sim.pwm, applied)
    assert np.all(sim.true_field(np.full(7, 0.5), rig.key_points) >= 0)


@pytest.mark.parametrize('bad', [np.full(6, 0.5), np.array([0.5] * 6 + [np.nan])])
def test_apply_rejects_wrong_shape_or_nan(tunnel, bad):
    with pytest.raises(CommandError):
        tunnel.apply(bad)


def test_true_field_does_not_change_the_commanded_state(tunnel, rig):
    tunnel.apply(np.full(7, 0.3))
    tunnel.true_field(np.full(7, 0.6), rig.key_points)
    assert np.allclose(tunnel.pwm, 0.3)


# -- determinism -----------------------------------------------------------------------------------
def _two_sweeps(rig, seed):
    sim = SimulatedTunnel(rig, seed=seed)
    sim.apply(np.full(7, 0.5))
    return sim.sweep(), sim.sweep()


def test_same_seed_same_sweeps_different_seed_different(rig):
    a1, a2 = _two_sweeps(rig, 3)
    b1, b2 = _two_sweeps(rig, 3)
    c1, _ = _two_sweeps(rig, 4)
    assert np.array_equal(a1.forces, b1.forces) and np.array_equal(a2.positions, b2.positions)
    assert not np.allclose(a1.positions, a2.positions)  # each call draws afresh
    assert not np.allclose(a1.forces, c1.forces)


def test_explicit_rng_is_reproducible_and_leaves_the_call_counter(tunnel):
    tunnel.apply(np.full(7, 0.5))
    s1 = tunnel.sweep(200, rng=np.random.default_rng(11))
    s2 = tunnel.sweep(200, rng=np.random.default_rng(11))
    assert np.array_equal(s1.forces, s2.forces) and tunnel.call_count == 0
    tunnel.measure_at(np.zeros((1, 2)))
    assert tunnel.call_count == 1


def test_build_is_fixed_by_default_and_varies_with_build_seed(rig):
    a, b = SimulatedTunnel(rig, seed=1), SimulatedTunnel(rig, seed=2)
    c = SimulatedTunnel(rig, build_seed=8)
    assert np.array_equal(a.imperfections.gain, b.imperfections.gain)
    assert not np.allclose(a.imperfections.gain, c.imperfections.gain)
    imp = a.imperfections
    assert np.all(np.abs(imp.gain - 1) < 0.21) and np.all(np.abs(imp.width_scale - 1) < 0.16)
    assert 0.003 < np.mean(np.hypot(*imp.offset.T)) < 0.02


def test_build_imperfections_act_on_thrust_landing_and_width(tunnel, perfect, rig, lone):
    imp, pwm = tunnel.imperfections, np.full(7, 0.5)
    assert np.allclose(tunnel.thrust(pwm) / perfect.thrust(pwm), imp.gain)
    k = rig.fans.index('HM3')
    hub, landing = rig.fans.positions[k], rig.fans.positions[k] + imp.offset[k]
    d = np.array([[0.0, 0.0], [0.06, 0.0], [0.0, -0.1]])
    expected = perfect.point_field(lone('HM3'), hub + d / imp.width_scale[k]) * imp.gain[k]
    assert np.allclose(tunnel.point_field(lone('HM3'), landing + d), expected)


# -- sweeps ------------------------------------------------------------------------------------------
@pytest.mark.parametrize('path, min_cover', [(TourPath(), 0.97), (RandomWalkPath(), 0.6)])
def test_sweep_shape_timing_and_coverage(rig, path, min_cover):
    sim = SimulatedTunnel(rig, path=path)
    sim.apply(np.full(7, 0.5))
    sweep = sim.sweep()
    assert isinstance(sweep, Sweep) and len(sweep) == 1000
    assert np.allclose(np.diff(sweep.times), 0.02)
    assert np.all(np.hypot(*sweep.positions.T) <= rig.sweep_radius + 0.003)
    d = np.min(np.linalg.norm(rig.key_points[:, None] - sweep.positions[None], axis=2), axis=1)
    assert np.mean(d < 0.03) >= min_cover
    step = np.linalg.norm(np.diff(sweep.positions, axis=0), axis=1)
    assert step.max() < 0.03  # smooth: no jumps between 50 Hz samples


def test_dropouts_give_nan_positions(rig):
    sim = SimulatedTunnel(rig, noise=NoiseModel(dropout=0.1))
    sweep = sim.sweep()
    lost = np.isnan(sweep.positions[:, 0]).mean()
    assert 0.05 < lost < 0.15 and len(sweep.finite()) == 1000 - np.isnan(sweep.positions[:, 0]).sum()


# -- noise -------------------------------------------------------------------------------------------
def _residuals(rig, noise, n=4000):
    sim = SimulatedTunnel(rig, noise=noise)
    sim.apply(np.full(7, 0.5))
    sweep = sim.sweep(n)  # position_sd = 0: recorded positions are the true ones
    return sweep.forces, sim.true_field(sweep.pwm, sweep.positions)


def test_additive_noise_sd_and_time_correlation(rig):
    measured, true = _residuals(rig, NoiseModel(relative=0.0, absolute=0.03, position_sd=0.0))
    res = measured - true
    assert abs(res.std() - 0.03) < 0.003 and abs(res.mean()) < 0.005
    lag1 = np.corrcoef(res[:-1], res[1:])[0, 1]
    assert abs(lag1 - 0.5 * np.exp(-0.02 / 0.1)) < 0.08  # half the variance is AR(1), 0.1 s


def test_relative_noise_sd(rig):
    measured, true = _residuals(rig, NoiseModel(relative=0.04, absolute=0.0, position_sd=0.0))
    assert abs((measured / true - 1).std() - 0.04) < 0.004


def test_measure_at_mean_is_unbiased_with_the_configured_spread(tunnel, rig):
    pwm = np.full(7, 0.5)
    tunnel.apply(pwm)
    n, noise = 20, tunnel.noise
    measured = tunnel.measure_at(rig.key_points, samples_per_point=n)
    true = tunnel.true_field(pwm, rig.key_points)
    phi = np.exp(-1 / (tunnel.sample_rate_hz * noise.correlation_time))
    lags = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    var_ar = np.sum(phi ** lags) / n ** 2
    f = noise.correlated_fraction
    sd_mean = noise.sd(true) * np.sqrt(f * var_ar + (1 - f) / n)
    z = (measured - true) / sd_mean
    assert abs(z.mean()) < 0.25 and 0.75 < z.std() < 1.25


def test_zero_noise_measures_the_truth(perfect, rig):
    perfect.apply(np.full(7, 0.4))
    assert np.allclose(perfect.measure_at(rig.key_points[:20], 5),
                       perfect.true_field(np.full(7, 0.4), rig.key_points[:20]))


# -- the plant's shape -------------------------------------------------------------------------------
def test_equal_pwm_field_is_lopsided(tunnel, perfect, rig):
    pwm, kp = np.full(7, 0.5), rig.key_points
    inner = kp[np.hypot(*kp.T) <= 0.3]
    assert ring_lopsidedness(tunnel, pwm, kp) >= 0.15  # measured 0.30 (perfect build 0.09)
    assert c3_asymmetry(tunnel, pwm, inner) >= 0.10  # measured 0.18: from the build
    assert c3_asymmetry(perfect, pwm, inner) < 0.02  # the perfect rig is symmetric


def test_lone_fan_forces_match_the_tuned_curves(perfect, rig, lone):
    hubs = dict(zip(rig.fans.names, rig.fans.positions))
    over = {(n, u): perfect.true_field(lone(n, u), hubs[n][None])[0]
            for n in ('LM1', 'HM1') for u in (0.5, 0.65)}
    for u, lo, hi in ((0.5, 3.0, 4.0), (0.65, 5.0, 6.5)):
        assert lo <= over['LM1', u] < over['HM1', u] <= hi
    ring = perfect.true_field(lone('CM'), np.array([[0.19, 0.0]]))[0]
    assert ring < over['LM1', 0.5]  # the central fan is a bit weaker


def test_central_fan_raises_the_ring_more_than_the_axis(tunnel, rig):
    low, high = np.full(7, 0.5), np.full(7, 0.5)
    low[6], high[6] = 0.2, 0.6
    pts = np.vstack([[0.0, 0.0], rig.fans.positions[:6]])
    gain = tunnel.true_field(high, pts) - tunnel.true_field(low, pts)
    assert np.all(gain[1:] > 1.1 * gain[0])  # measured 1.20-1.29 x the axis gain


def test_footprint_is_flat_topped_not_gaussian(perfect, rig, lone):
    hub = rig.fans.positions[0]
    d = np.array([0.0, 0.05, 0.10, 0.14, 0.20])
    f = perfect.point_field(lone('LM1'), hub + np.column_stack([0 * d, d]))
    f = f / f[0]
    assert np.allclose(f, np.exp(-(d / 0.14) ** 2.4), atol=1e-9)
    gauss = np.exp(-(d / 0.14) ** 2)  # a Gaussian of the same width falls faster near the top
    assert f[1] > gauss[1] and f[4] < gauss[4]


def test_true_field_is_the_plate_average_of_the_point_field(tunnel, rig):
    pwm, c = np.full(7, 0.5), np.array([[0.12, -0.07], [0.0, 0.25]])
    g = (np.arange(60) + 0.5) / 60 * rig.plate_side - rig.plate_side / 2
    xx, yy = np.meshgrid(g, g)
    grid = np.column_stack([xx.ravel(), yy.ravel()])
    fine = np.array([tunnel.point_field(pwm, p + grid).mean() for p in c])
    assert np.allclose(tunnel.true_field(pwm, c), fine, rtol=2e-3)
    finer = SimulatedTunnel(rig, plate_order=9).true_field(pwm, rig.key_points)
    assert np.allclose(tunnel.true_field(pwm, rig.key_points), finer, rtol=2e-3)


def test_tiled_and_dense_evaluation_agree():
    rng = np.random.default_rng(0)
    n = 300
    group = JetGroup(FlatTop(2.4), rng.uniform(-1, 1, (n, 2)), rng.uniform(0, 3, n),
                     rng.uniform(0.1, 0.2, n), np.arange(n))
    pts = rng.uniform(-1.2, 1.2, (5000, 2))
    assert np.allclose(group.density(pts), _block(pts, group), rtol=1e-12, atol=1e-12)


def test_fan_wall_runs_with_square_wall_and_effects():
    from wind_shaper.sim import ElongatedFootprint, JetInteraction, Swirl, WallBoundaryLayer
    fans = FanArray.grid(12, 12, 0.08)
    geo = TunnelGeometry(fans=fans, key_points=rect_key_points(0.4, 0.4, 20, 20), wall_radius=0.5,
                         sweep_radius=0.45, extra={'wall_shape': 'square'})
    sim = SimulatedTunnel(geo, effects=[JetInteraction(), Swirl(), WallBoundaryLayer(),
                                        ElongatedFootprint(fan='F05_05')])
    sim.apply(np.full(fans.n_fans, 0.5))
    f = sim.true_field(sim.pwm, geo.key_points)
    assert f.shape == (400,) and np.all(np.isfinite(f)) and f.min() > 0
    assert len(sim.sweep(300)) == 300


# -- reachability (the paper's three targets) ------------------------------------------------------
def _fit(tunnel, target, x0=0.5):
    kp = tunnel.geometry.key_points
    res = least_squares(lambda u: tunnel.true_field(u, kp) - target, np.full(7, x0),
                        bounds=(0.0, 0.65), diff_step=1e-3)
    return res.x, float(np.sqrt(np.mean(res.fun ** 2)))


def test_paper_targets_are_roughly_reachable(tunnel, rig):
    kp = rig.key_points
    r2 = np.sum(kp ** 2, axis=1)
    u, rms = _fit(tunnel, np.full(len(kp), 2.5))
    assert rms < 0.8  # measured 0.73 N
    u, rms = _fit(tunnel, 2.25 + 30 * r2)
    assert rms < 2.6 and u[6] <= 0.05  # measured 2.46 N, central fan at 0 as in the paper
    assert np.all(u[:6] > 0.45)
    lm1 = rig.fans.positions[0]
    u, rms = _fit(tunnel, 1.5 + 3.0 * np.exp(-np.sum((kp - lm1) ** 2, axis=1) / (2 * 0.12 ** 2)), 0.3)
    assert rms < 0.5 and np.argmax(u) == 0  # measured 0.44 N, LM1 highest


# -- config ----------------------------------------------------------------------------------------
def test_from_config_file(rig):
    cfg = yaml.safe_load(CONFIG.read_text())
    sim = SimulatedTunnel.from_config(rig, cfg)
    assert sim.seed == 0 and sim.effects == () and sim.noise == NoiseModel()
    same = SimulatedTunnel.from_config(rig, cfg['sim'])
    assert np.array_equal(same.imperfections.gain, sim.imperfections.gain)


def test_from_config_options(rig):
    sim = SimulatedTunnel.from_config(rig, {'seed': 5, 'noise': 'zero', 'imperfections': 'none',
                                            'path': {'kind': 'walk', 'speed': 0.5},
                                            'effects': [{'name': 'weak_fan', 'fan': 'LM1', 'gain': 0.5}]})
    assert sim.seed == 5 and sim.noise == NoiseModel.zero() and isinstance(sim.path, RandomWalkPath)
    assert np.all(sim.imperfections.gain == 1) and sim.effects[0].truth() == {'fan': 'LM1', 'gain': 0.5}
    with pytest.raises(ConfigError, match='unknown sim config keys'):
        SimulatedTunnel.from_config(rig, {'sedd': 1})
    with pytest.raises(ConfigError):
        SimulatedTunnel.from_config(rig, {'noise': {'relativ': 0.1}})
    with pytest.raises(ConfigError):
        SimulatedTunnel(rig, imperfections=Imperfections.none(3))


# -- another jet form ----------------------------------------------------------------------------
def test_heavy_tailed_jets_keep_the_force_over_the_hub_and_fall_off_slower(rig, lone):
    from wind_shaper.sim import PlantConstants
    flat = SimulatedTunnel(rig, imperfections=Imperfections.none(7), noise=NoiseModel.zero())
    heavy = SimulatedTunnel(rig, imperfections=Imperfections.none(7), noise=NoiseModel.zero(),
                            constants=PlantConstants(profile='heavy_tail', tail=3.0))
    hub = rig.fans.positions[rig.fans.index('HM2')]
    # the amplitude is normalised on the plate over the hub: the same force there
    assert heavy.true_field(lone('HM2'), hub[None])[0] == pytest.approx(
        flat.true_field(lone('HM2'), hub[None])[0], rel=1e-6)
    far = hub + np.array([0.0, 0.0]) - 0.3 * hub / np.linalg.norm(hub)  # 30 cm towards the axis
    assert heavy.true_field(lone('HM2'), far[None])[0] > 2 * flat.true_field(lone('HM2'), far[None])[0]


def test_unknown_jet_profile_is_refused_with_the_choices():
    from wind_shaper.sim import PlantConstants
    with pytest.raises(ConfigError, match='flat_top'):
        PlantConstants(profile='top_hat')
    with pytest.raises(ConfigError, match='tail'):
        PlantConstants(profile='heavy_tail', tail=0.5)
