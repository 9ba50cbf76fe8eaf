"""Region sweeps: after a step, sweep only where the model says the field changed; carry the
rest over with its predicted change and an honest std; check the carried values where the
region was swept."""
from dataclasses import replace

import numpy as np
import pytest

from wind_shaper.app import Setup, shaping_loop_on_sim
from wind_shaper.control.region import RegionPlan, SweepRegion, carry_over, change_error_after, plan_region
from wind_shaper.control.sweep_length import SweepLength, fused_estimate
from wind_shaper.core.area import SweepArea
from wind_shaper.core.errors import ConfigError, SweepError
from wind_shaper.estimation import Coverage, FieldEstimator
from wind_shaper.sim import NoiseModel
from wind_shaper.sim.paths import TourPath


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


class Linear:
    """A model whose field is G @ U at the key points it was built for."""

    def __init__(self, G):
        self.G = np.asarray(G, float)

    def __call__(self, U, Z):
        return self.G @ np.asarray(U, float)


def _grid(n=11, half=0.3):
    g = np.linspace(-half, half, n)
    X, Y = np.meshgrid(g, g)
    P = np.column_stack([X.ravel(), Y.ravel()])
    return P[np.hypot(P[:, 0], P[:, 1]) <= half]


def test_the_carried_field_moves_by_the_predicted_change_and_its_std_grows_with_it():
    G = np.array([[1.0, 0.0], [0.0, 2.0], [0.5, 0.5]])
    mean, std = carry_over(Linear(G), [0.2, 0.2], [0.3, 0.2], np.zeros((3, 2)),
                           [1.0, 2.0, 3.0], [0.01, 0.01, 0.01], change_error=0.5)
    np.testing.assert_allclose(mean, [1.1, 2.0, 3.05])
    np.testing.assert_allclose(std, np.sqrt(0.01 ** 2 + (0.5 * np.array([0.1, 0.0, 0.05])) ** 2))


def test_only_the_key_points_the_step_changed_are_swept_and_the_rest_is_a_compact_patch():
    kp = _grid()
    # fan 0 acts on the right half only, fan 1 everywhere but weakly
    G = np.column_stack([(kp[:, 0] > 0.05) * 1.0, np.full(len(kp), 0.01)])
    policy = SweepRegion(enabled=True, change_error=0.5, min_share=0.1, max_share=0.75)
    prev = np.zeros(len(kp)), np.full(len(kp), 0.02)
    plan = plan_region(policy, Linear(G), kp, [0.3, 0.3], [0.5, 0.3], *prev, std_max=0.05)
    assert np.array_equal(plan.needed, kp[:, 0] > 0.05)
    assert plan.area.contains(kp[plan.needed]).all()
    assert np.all(plan.carried_std[~plan.needed] <= 0.05)
    # a step that changes nearly nothing: a compact patch of min_share around the stalest point
    std = np.full(len(kp), 0.02)
    std[40] = 0.045
    plan = plan_region(policy, Linear(G), kp, [0.3, 0.3], [0.3, 0.31], np.zeros(len(kp)), std, std_max=0.05)
    assert plan.needed.sum() == int(np.ceil(0.1 * len(kp))) and plan.needed[40]
    assert np.max(np.linalg.norm(kp[plan.needed] - kp[40], axis=1)) < 0.13
    # a step that changes most of the field: the whole area; off: the whole area
    assert plan_region(policy, Linear(np.ones((len(kp), 2))), kp, [0.3, 0.3], [0.5, 0.5], *prev, std_max=0.05) is None
    assert plan_region(SweepRegion(), Linear(G), kp, [0.3, 0.3], [0.5, 0.3], *prev, std_max=0.05) is None


def test_fusion_weighs_by_inverse_variance_and_consistency_judges_the_carried_values():
    plan = RegionPlan(np.array([True, True, False]), np.array([1.0, 1.0, 1.0]),
                      np.array([0.1, 0.1, 0.01]), SweepArea(np.zeros((2, 2)), 0.1), 0.5)
    mean, std = plan.fuse([2.0, 2.0, 5.0], [0.1, 0.01, 10.0])
    np.testing.assert_allclose(mean[:2], [1.5, 1.0 + 100 / 101])
    assert mean[2] == pytest.approx(1.0, abs=1e-5) and std[2] == pytest.approx(0.01, rel=1e-4)
    # the fresh values 10 std away where swept: far from 1; right on: 0; no sure point: NaN
    assert plan.consistency([2.0, 2.0, 0.0], [0.01, 0.01, 1.0]) > 50
    assert plan.consistency([1.0, 1.0, 0.0], [0.01, 0.01, 1.0]) == 0.0
    assert np.isnan(plan.consistency([1.0, 1.0, 0.0], [1.0, 1.0, 1.0]))
    policy = SweepRegion(enabled=True, change_error=0.5)
    assert change_error_after(policy, 0.7) == 0.5 and change_error_after(policy, float('nan')) == 0.5
    assert change_error_after(policy, 9.0) == pytest.approx(1.5)


def test_a_region_path_keeps_to_the_region_and_passes_its_key_points_sooner():
    kp = _grid()
    needed = (kp[:, 0] > 0.1) & (kp[:, 1] > 0.0)
    area = SweepArea(kp[needed], 0.10)

    def samples_to_cover(**region):
        p = TourPath()(1000, 0.02, 0.34, np.random.default_rng(4), **region)
        cov = Coverage(kp[needed], 0.08)
        for i in range(len(p)):
            cov.add(p[i])
            if cov.share == 1.0:
                return i + 1, p
        return None, p

    n_region, p = samples_to_cover(region=area)
    n_whole, _ = samples_to_cover()
    assert n_region is not None and n_whole is not None and n_region < 0.6 * n_whole, (n_region, n_whole)
    assert np.mean(area.contains(p)) > 0.85
    assert np.all(np.hypot(p[:, 0], p[:, 1]) <= 0.34 + 1e-9)


def test_the_estimator_needs_only_the_region_key_points_passed(setup):
    sim = setup.make_sim(seed=1)
    kp = setup.geometry.key_points
    sim.apply(np.full(7, 0.4))
    needed = kp[:, 0] > 0.12
    sweep = sim.sweep(300, region=SweepArea(kp[needed], 0.10))
    est = FieldEstimator().estimate(sweep, kp, required=needed)
    assert est.std[needed].max() < est.std[~needed].max()
    with pytest.raises(SweepError, match='missed .* the whole area'):
        FieldEstimator().estimate(sweep, kp)
    with pytest.raises(SweepError, match='region asked for'):
        FieldEstimator().estimate(sweep, kp, required=~needed)


def _region_loop(setup, target, seed, *, sim=None, model=None, enabled=True):
    loop, _ = shaping_loop_on_sim(setup, target, seed=seed, sim=sim, model=model)
    loop.sweep_length = replace(loop.sweep_length, region={'enabled': enabled})
    return loop


def test_region_sweeps_are_shorter_and_their_std_no_less_honest_than_whole_sweeps(setup):
    """On the simulated tunnel: after the first sweep the region sweeps last less plate time
    than whole sweeps, and the fused estimate's error against the true field, in units of its
    std, is no larger than a whole sweep's GP estimate's (carrying over adds no overconfidence;
    both are overconfident on this simulator, whose noise is not the GP's white noise)."""
    plate = {True: [], False: []}
    z = {True: [], False: []}
    for seed in (1, 2):
        for enabled in (True, False):
            loop = _region_loop(setup, 'gaussian@LM1', seed, enabled=enabled)
            records = loop.run(4)
            plate[enabled] += [r.plate_s for r in records[1:]]
            z[enabled] += [(r.estimate.mean - r.true_field) / r.estimate.std for r in records[1:]]
            if enabled:
                assert all('region' in r.info for r in records[2:])
    assert np.mean(plate[True]) < 0.7 * np.mean(plate[False]), plate
    rms = {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in z.items()}
    assert rms[True] < 1.1 * rms[False], rms


def test_the_region_sweep_catches_a_model_whose_predicted_change_is_wrong(setup):
    """One fan's step on the noise-free simulated tunnel: carried over with the prior's change,
    the field agrees with the fresh estimate where the region is swept; with a model claiming
    three times the change it does not, and the next plan's change error grows."""
    kp = setup.geometry.key_points
    sim = setup.make_sim(seed=3)
    sim.noise = NoiseModel.zero()
    estimator = FieldEstimator()
    U0 = np.full(7, 0.4)
    U1 = U0.copy()
    U1[setup.geometry.fans.names.index('LM1')] += 0.15
    sim.apply(U0)
    prev = estimator.estimate(sim.sweep(1000), kp)
    sim.apply(U1)
    policy = SweepRegion(enabled=True, max_share=0.9)
    model = setup.load_model()
    theta = model.theta * np.where(['thrust' in n for n in model.theta_names], 3.0, 1.0)
    checks = {}
    for name, m in (('prior', model), ('3x', model.with_theta(theta))):
        plan = plan_region(policy, m, kp, U0, U1, prev.mean, prev.std, std_max=0.06)
        assert plan is not None and 0.1 < plan.share < 0.9
        sweep = sim.sweep(600, region=plan.area, rng=np.random.default_rng(5))
        fused, checks[name] = fused_estimate(estimator, sweep, kp, plan)
    assert checks['prior'] < 1.0 < checks['3x'] and checks['3x'] > 4 * checks['prior'], checks
    assert change_error_after(policy, checks['3x']) > policy.change_error


@pytest.mark.parametrize('bad, words', [({'enabled': 'yes'}, 'enabled'), ({'change_error': -1}, 'change_error'),
                                        ({'min_share': 0.9, 'max_share': 0.5}, 'min_share'),
                                        ({'reach': 0}, 'reach'), ({'enable': True}, 'unknown keys')])
def test_bad_region_settings_are_named(bad, words):
    with pytest.raises(ConfigError, match=words):
        SweepLength(region=bad)
