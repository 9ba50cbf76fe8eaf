"""The warm start (the prior's bounded optimum), the check of the first sweep against it, and
sweeps that end once the estimate is good enough."""
import numpy as np
import pytest
from scipy.optimize import least_squares

from wind_shaper.app import Setup, shaping_loop_on_sim
from wind_shaper.control import ShapingLoop
from wind_shaper.control.sweep_length import SweepLength
from wind_shaper.control.warm_start import first_step_rule, warm_start
from wind_shaper.core.errors import ConfigError


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


def _prior_optimum(model, kp, target, on, lo, hi, starts=4):
    rng = np.random.default_rng(0)
    best = np.inf
    for s in range(starts):
        x0 = np.full(on.sum(), 0.5) if s == 0 else rng.uniform(lo, hi, on.sum())

        def f(x):
            U = np.zeros(len(on))
            U[on] = x
            return model(U, kp) - target
        best = min(best, float(np.sqrt(np.mean(least_squares(f, x0, bounds=(lo, hi)).fun ** 2))))
    return best


@pytest.mark.parametrize('spec, disabled', [('uniform', ()), ('gaussian@LM1', ()), ('parabolic', ('CM',))])
def test_the_warm_start_is_the_prior_optimum_within_the_bounds(spec, disabled):
    setup = Setup.load(disabled=disabled)
    kp, on, b = setup.geometry.key_points, setup.geometry.fans.enabled, setup.shaping.bounds
    model = setup.load_model()
    target = setup.make_target(spec).values(kp)
    ws = warm_start(model, kp, target, b, on, fan_names=setup.geometry.fans.names,
                    model_error=setup.model_error())
    assert np.all(ws.U[on] >= b.u_min) and np.all(ws.U[on] <= b.u_max) and np.all(ws.U[~on] == 0)
    # as good as a multi-start least-squares search on the prior, and far better than U = 0.5
    assert ws.predicted_rmse <= _prior_optimum(model, kp, target, on, b.u_min, b.u_max) + 1e-3
    assert ws.predicted_rmse <= ws.start_rmse
    assert ws.model_error == pytest.approx(setup.model_error()) and np.isfinite(ws.model_error)


def test_a_target_beyond_the_fans_puts_them_on_the_bound_and_says_so(setup):
    kp, on, b = setup.geometry.key_points, setup.geometry.fans.enabled, setup.shaping.bounds
    ws = warm_start(setup.load_model(), kp, np.full(len(kp), 30.0), b, on,
                    fan_names=setup.geometry.fans.names)
    assert ws.on_bound and set(ws.at_upper) == set(setup.geometry.fans.names)
    assert 'u_max = 0.65' in ws.notes[0]
    assert np.all(ws.U <= b.u_max)   # never outside the bounds


def test_the_first_sweep_is_checked_against_the_prediction(setup):
    kp, on, b = setup.geometry.key_points, setup.geometry.fans.enabled, setup.shaping.bounds
    ws = warm_start(setup.load_model(), kp, setup.make_target('uniform').values(kp), b, on,
                    model_error=0.2)
    std = np.full(len(kp), 0.05)
    agree = ws.compare(ws.predicted + 0.1, std)
    assert not agree.mismatch and 'agrees' in agree.text()
    far = ws.compare(ws.predicted + 1.0, std)   # 1 N everywhere: 4.9 x what 0.2 N allows
    assert far.mismatch and far.ratio == pytest.approx(1.0 / np.hypot(0.2, 0.05))
    assert 'does not match this tunnel' in far.text() and 'collect --design lhs:6' in far.text()
    # a mismatch sets the commissioning's maps aside and keeps the trust radius; an agreement
    # leaves the rule as it is
    rule = setup.shaping.make_rule()
    assert rule.commissioning_weight > 0
    after = first_step_rule(rule, far)
    assert after.commissioning_weight == 0 and after.radius == rule.radius
    assert first_step_rule(rule, agree) is rule
    # without a calibration error in the model file nothing can be judged
    unknown = warm_start(setup.load_model(), kp, setup.make_target('uniform').values(kp), b, on)
    check = unknown.compare(unknown.predicted + 1.0, std)
    assert not check.checked and not check.mismatch and 'not judged' in check.text()


def test_a_prior_of_another_tunnel_is_flagged_by_the_first_sweep(setup):
    # the prior of the shipped tunnel on a tunnel whose fans all give 45 % less thrust: the
    # warm start's prediction is far off, the loop says so and steps from the measured field
    # with the rule's own trust radius
    from wind_shaper.sim import make_effect
    sim = setup.make_sim(seed=1, effects=[make_effect('weak_fan', fan=f, gain=0.55)
                                          for f in setup.geometry.fans.names])
    loop, _ = shaping_loop_on_sim(setup, 'uniform', seed=1, sim=sim)
    rec = loop.iterate()
    check = rec.info['warm_start']['check']
    assert check['mismatch'] is True and check['ratio'] > 3, check
    assert rec.info['radius'] == pytest.approx(setup.shaping.make_rule().radius)
    # on the tunnel it was fitted to, the same check passes
    loop, _ = shaping_loop_on_sim(setup, 'uniform', seed=1)
    assert loop.iterate().info['warm_start']['check']['mismatch'] is False


def test_u0_still_overrides_the_warm_start(setup):
    loop, _ = shaping_loop_on_sim(setup, 'uniform', u0=0.5)
    assert loop.warm is None and np.allclose(loop.U[setup.geometry.fans.enabled], 0.5)
    with pytest.raises(ConfigError, match="'warm'"):
        ShapingLoop(setup.make_sim(), setup.load_model(), np.zeros(len(setup.geometry.key_points)),
                    setup.shaping.make_rule(), u0='cold')


def test_a_sweep_ends_once_every_key_point_is_passed_and_the_estimate_is_good_enough(setup):
    seen = []
    loop, _ = shaping_loop_on_sim(setup, 'parabolic', seed=2, on_progress=seen.append)
    rec = loop.iterate()
    policy = setup.shaping.make_sweep_length()
    n = len(rec.sweep)
    assert policy.min_samples <= n < setup.shaping.samples_per_sweep
    assert seen[-1].enough and seen[-1].coverage == 1.0 and seen[-1].n_samples == n
    threshold = policy.std_max(loop.rule)
    assert seen[-1].std_rms <= threshold and seen[-1].std_max <= policy.worst_factor * threshold
    assert not any(p.enough for p in seen[:-1])       # it ended at the first chance
    assert rec.plate_s == pytest.approx(n / 50.0)     # 50 Hz
    # the samples are the first n of the full sweep with the same draws
    full = setup.make_sim(seed=2)
    full.apply(rec.pwm)
    np.testing.assert_array_equal(full.sweep(setup.shaping.samples_per_sweep).forces[:n], rec.sweep.forces)
    # a fixed length when asked
    fixed, _ = shaping_loop_on_sim(setup, 'parabolic', seed=2)
    fixed.sweep_length = SweepLength(adaptive=False)
    assert len(fixed.iterate().sweep) == setup.shaping.samples_per_sweep


def test_tunnel_time_is_counted_per_iteration_and_in_total(setup):
    loop, _ = shaping_loop_on_sim(setup, 'parabolic', seed=3)
    records = loop.run(2)
    used = loop.tunnel_time()
    assert used['plate_s'] == [pytest.approx(r.plate_s) for r in records]
    assert used['settle_total_s'] == pytest.approx(setup.shaping.fan_settle_s * len(records))
    assert used['total_s'] == pytest.approx(used['plate_total_s'] + used['settle_total_s'])
    assert records[0].to_json()['plate_s'] == pytest.approx(records[0].plate_s, abs=1e-3)


@pytest.mark.parametrize('bad, words', [({'min_samples': 5}, 'min_samples'), ({'chunk_samples': 0}, 'chunk_samples'),
                                        ({'std_factor': 0.0}, 'std_factor'),
                                        ({'worst_factor': 0.5}, 'worst_factor')])
def test_bad_sweep_settings_are_named(bad, words):
    with pytest.raises(ConfigError, match=words):
        SweepLength(**bad)
