"""Algorithm 1's update: the pseudo-inverse step, the schedule, bounds and disabled fans."""
import numpy as np
import pytest

from wind_shaper.core.errors import ConfigError
from wind_shaper.control import CommandBounds, PaperUpdate, UpdateInput


def test_schedule_is_the_papers():
    rule = PaperUpdate()
    assert [round(rule.step_size(k), 6) for k in range(4)] == [0.8, 0.4, 0.266667, 0.2]


def test_step_solves_a_linear_problem_scaled_by_lambda(rng):
    J = rng.normal(size=(50, 4))
    du = np.array([0.1, -0.05, 0.02, 0.0])
    U = np.full(4, 0.3)
    step = PaperUpdate(gain=0.8).step(UpdateInput(0, U, J @ du, J, np.ones(4, bool)))
    np.testing.assert_allclose(step.raw_step, du, atol=1e-12)
    np.testing.assert_allclose(step.U_next, U + 0.8 * du, atol=1e-12)


def test_commands_never_leave_bounds_and_disabled_fans_stay_zero(rng):
    rule = PaperUpdate(bounds=CommandBounds(0.0, 0.65))
    enabled = np.array([True, True, False, True])
    for k in range(200):
        J = rng.normal(size=(30, 4)) * rng.uniform(0.01, 10)
        delta = rng.normal(size=30) * rng.uniform(0.1, 100)
        U = rng.uniform(0, 0.65, 4) * enabled
        out = rule.step(UpdateInput(k % 12, U, delta, J, enabled)).U_next
        assert np.all(out >= 0.0) and np.all(out <= 0.65)
        assert out[2] == 0.0


def test_disabled_fans_do_not_take_part_in_the_solve(rng):
    J = rng.normal(size=(40, 3))
    J[:, 1] = J[:, 0]  # a disabled fan identical to fan 0 would otherwise split the step
    du = np.array([0.1, 0.0, 0.05])
    enabled = np.array([True, False, True])
    step = PaperUpdate().step(UpdateInput(0, np.full(3, 0.3), J @ du, J, enabled))
    np.testing.assert_allclose(step.raw_step, du, atol=1e-12)


def test_bad_bounds_and_nan_are_refused():
    with pytest.raises(ConfigError, match='u_min < u_max'):
        CommandBounds(0.7, 0.6)
    with pytest.raises(ConfigError, match='u_max <= 1'):
        CommandBounds(0.0, 1.5)
    with pytest.raises(ConfigError, match='NaN'):
        CommandBounds().project(np.array([0.1, np.nan]), np.ones(2, bool))


def test_a_nearly_flat_fan_is_not_thrown_to_full_pwm(rng):
    # A fan idling at PWM ~0 with a flat thrust curve has a ~zero Jacobian column; inverting
    # that singular value (machine-precision cut-off) would make a huge step for it.
    J = rng.normal(size=(60, 3))
    J[:, 2] *= 1e-6
    delta = rng.normal(size=60)
    U = np.array([0.3, 0.3, 1e-5])
    safe = PaperUpdate().step(UpdateInput(0, U, delta, J, np.ones(3, bool)))
    assert abs(safe.raw_step[2]) < 1.0
    naive = PaperUpdate(rcond=1e-15).step(UpdateInput(0, U, delta, J, np.ones(3, bool)))
    assert abs(naive.raw_step[2]) > 100  # what the cut-off prevents


def test_a_shared_gain_prior_moves_a_fan_no_map_has_seen_running_with_the_others():
    """Every fan 20 % weaker than the prior, a map where the central fan is off: with independent
    gains its correction stays at the prior (1.0); with a shared part it follows the others, and
    the fit of the fans that ran is not worse."""
    from wind_shaper.control.basis import FanBasis
    from wind_shaper.control.shape_fit import ShapeFit
    from wind_shaper.app import Setup
    setup = Setup.load()
    model, Z = setup.load_model(), setup.geometry.key_points
    basis = FanBasis.from_term(model, Z)
    n = model.n_fans
    U = np.full(n, 0.5)
    U[-1] = 0.0                                   # the central fan idle in the only map
    a, _ = basis.thrust(U)
    F = basis.offset + 0.8 * (basis.shape @ a)    # the truth: every gain 0.8
    on = np.ones(n, bool)
    w = np.ones(len(Z))
    alone = ShapeFit(bases=('gain',), swirl=False, noise_std=0.1).fit(basis, [(U, F, w)], on)
    shared = ShapeFit(bases=('gain',), swirl=False, noise_std=0.1, gain_common_sd=0.3).fit(basis, [(U, F, w)], on)
    assert alone[n] == pytest.approx(1.0, abs=1e-6)          # the idle fan: the prior's gain
    assert shared[n] < 0.9                                    # follows the others' 0.8
    assert np.allclose(shared[1:n], 0.8, atol=0.03) and np.allclose(alone[1:n], 0.8, atol=0.03)


def _reference_basis():
    """The reference prior's fan basis at the key points: (basis, n_fans, every fan on, unit
    weights per key point)."""
    from wind_shaper.app import Setup
    from wind_shaper.control.basis import FanBasis
    setup = Setup.load()
    model, Z = setup.load_model(), setup.geometry.key_points
    return FanBasis.from_term(model, Z), model.n_fans, np.ones(model.n_fans, bool), np.ones(len(Z))


def _loaded_truth(basis, slope):
    """U -> the field [N] of the basis with every gain 1 + slope (mean U - LOAD_REF)."""
    from wind_shaper.control.shape_fit import LOAD_REF

    def truth(U):
        a, _ = basis.thrust(U)
        return basis.offset + (1 + slope * (np.mean(U) - LOAD_REF)) * (basis.shape @ a)
    return truth


def test_a_shared_load_slope_learns_that_every_fan_gives_less_the_harder_all_run():
    """A starved inlet: every gain falls with the fans' mean command L (gain 1 - 0.6 (L - 0.3)).
    Two maps at two loads: the load slope comes out near -0.6 and predicts a third load the
    per-fan gains alone cannot (they fit one level of the gains for both maps)."""
    from wind_shaper.control.shape_fit import ShapeFit
    basis, n, on, w = _reference_basis()
    truth = _loaded_truth(basis, -0.6)

    def predicted(fit, theta, U):
        a, _ = basis.thrust(U)
        return (basis.offset + theta[0] + fit.shape_matrix(basis, theta) @ a
                + fit.load_slope(theta) * ShapeFit.load(U, on) * (basis.shape @ a))

    maps = [(U, truth(U), w) for U in (np.full(n, 0.2), np.full(n, 0.6))]
    loaded = ShapeFit(bases=('gain',), swirl=False, noise_std=0.05, load_sd=1.0)
    plain = ShapeFit(bases=('gain',), swirl=False, noise_std=0.05)
    theta_l, theta_p = loaded.fit(basis, maps, on), plain.fit(basis, maps, on)
    assert loaded.load_slope(theta_l) == pytest.approx(-0.6, abs=0.1)
    assert plain.load_slope(theta_p) == 0.0 and len(theta_p) == len(theta_l) - 1
    U3 = np.full(n, 0.8)
    err_l = np.sqrt(np.mean((predicted(loaded, theta_l, U3) - truth(U3)) ** 2))
    err_p = np.sqrt(np.mean((predicted(plain, theta_p, U3) - truth(U3)) ** 2))
    assert err_l < 0.3 * err_p, (err_l, err_p)


def test_a_prior_without_a_closed_form_thrust_curve_is_interpolated_to_its_own_values():
    """The per-fan thrust curves of a composed prior (no polynomial to read) come from a table
    of the term's own values and slopes: exact for a cubic curve, within 0.1 % of the largest
    thrust where an ESC's dead band puts a kink between two nodes, and the term itself outside
    0..1."""
    from wind_shaper.app import Setup
    from wind_shaper.control.basis import FanBasis
    from wind_shaper.model.fan_effects import FanCurve
    from wind_shaper.model.flow_effects import DeadBand
    setup = Setup.load()
    fans, Z = setup.geometry.fans, setup.geometry.key_points
    reference = setup.load_model(setup.config_dir / 'reference.yaml')
    rng = np.random.default_rng(1)
    U = rng.uniform(0.0, 1.0, (200, fans.n_fans))
    for term, tolerance in ((FanCurve(fans, reference, group=['higher', 'lower', 'central'], bend=0.7), 1e-9),
                            (DeadBand(fans, reference, threshold=0.123, saturation=0.87), 1e-3)):
        basis = FanBasis.from_term(term, Z)
        top = float(np.max(basis._evaluated(np.ones((1, fans.n_fans)))[0]))
        for u in U:
            a, da = basis.thrust(u)
            a_direct, da_direct = basis._evaluated(u[None])
            assert np.max(np.abs(a - a_direct)) <= tolerance * top
            if tolerance < 1e-6:   # the slopes too, where the curve is smooth
                assert np.allclose(da, da_direct, rtol=1e-6, atol=1e-9 * top)
    outside = np.full(fans.n_fans, 1.02)
    assert np.allclose(basis.thrust(outside)[0], basis._evaluated(outside[None])[0])


def test_the_load_slope_never_rises_with_the_load():
    """Gains that grow as all fans run harder are not a shared supply or inlet (no such supply
    makes a fan stronger): the slope is held at 0 and the fit is the plain per-fan fit, while a
    falling slope is still learnt."""
    from wind_shaper.control.shape_fit import ShapeFit
    basis, n, on, w = _reference_basis()

    def maps(slope):
        truth = _loaded_truth(basis, slope)
        return [(U, truth(U), w) for U in (np.full(n, 0.2), np.full(n, 0.6))]

    loaded = ShapeFit(bases=('gain',), swirl=False, noise_std=0.05, load_sd=1.0)
    plain = ShapeFit(bases=('gain',), swirl=False, noise_std=0.05)
    rising = loaded.fit(basis, maps(+0.6), on)
    assert loaded.load_slope(rising) == 0.0
    assert np.allclose(rising[:-1], plain.fit(basis, maps(+0.6), on), atol=1e-9)
    assert loaded.load_slope(loaded.fit(basis, maps(-0.6), on)) == pytest.approx(-0.6, abs=0.1)


def test_the_load_slope_asks_for_a_dense_prior():
    from wind_shaper.app import Setup
    from wind_shaper.control.basis import FanBasis
    from wind_shaper.control.shape_fit import ShapeFit
    from wind_shaper.core.errors import ConfigError
    setup = Setup.load()
    model, Z = setup.load_model(), setup.geometry.key_points
    basis = FanBasis.from_term(model, Z, sparse=True)
    U = np.full(model.n_fans, 0.5)
    maps = [(U, np.zeros(len(Z)), np.ones(len(Z)))]
    with pytest.raises(ConfigError, match='load_sd'):
        ShapeFit(load_sd=0.5).fit(basis, maps, np.ones(model.n_fans, bool))
    ShapeFit().fit(basis, maps, np.ones(model.n_fans, bool))   # without it the sparse fit runs
