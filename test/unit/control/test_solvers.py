"""The adaptive update: bounds, disabled fans, the secant correction, the per-fan prior
factorisation and fit, the stopping rule, and the estimation pieces large walls need."""
import numpy as np
import pytest
from scipy.optimize import lsq_linear

from wind_shaper.core.errors import ConfigError
from wind_shaper.estimation.field import (FieldEstimator, GaussianProcessField, LocalGaussianProcessField,
                                    TurbulentGaussianProcessField, fit_hyperparameters)
from wind_shaper.estimation.local_turbulent import LocalTurbulentGaussianProcessField
from wind_shaper.core.geometry import FanArray, TunnelGeometry, rect_key_points
from wind_shaper.control import (AdaptiveUpdate, CommandBounds, FanBasis, PaperUpdate, PastIteration,
                                 SecantCorrection, ShapeFit, ShapingConfig, ShapingLoop, StoppingRule,
                                 UpdateInput, broyden_update)
from wind_shaper.model import CentralRing, FanJets, paper_prior

JETS = dict(thrust_higher=(0.1, 0.5, 15.0), thrust_lower=(0.1, 0.5, 12.0), sigma=0.16)
RING = dict(thrust=(0.0, 0.5, 11.0), offset=0.6, sigma=0.25)


@pytest.fixture
def prior(rig):
    return FanJets(rig.fans, **JETS) + CentralRing(rig.fans, **RING)


def _inputs(rig, prior, U, field, target, history=(), k=0, std=None, enabled=None, prior_maps=()):
    enabled = rig.fans.enabled if enabled is None else enabled
    return UpdateInput(k, U, target - field, None, enabled, std, model=prior,
                       key_points=rig.key_points, target=target, history=tuple(history),
                       prior_maps=tuple(prior_maps))


# -- bounds and disabled fans -------------------------------------------------------------------
@pytest.mark.parametrize('mode', ['full', 'jacobian_only', 'curve'])
def test_commands_stay_in_bounds_and_disabled_fans_stay_zero(rig, prior, rng, mode):
    bounds = CommandBounds(0.05, 0.6)
    rule = AdaptiveUpdate(bounds=bounds, curve_sd=0.15 if mode == 'curve' else 0.0)
    enabled = np.array([True, True, False, True, True, True, False])
    kp = rig.key_points
    bent = 0
    for trial in range(25):
        U = np.where(enabled, rng.uniform(0.0, 0.8, 7), rng.uniform(0, 1, 7))  # even out-of-bounds input
        target = rng.uniform(-5, 15) + rng.normal(0, 2) * np.exp(-np.sum((kp - rng.uniform(-.2, .2, 2)) ** 2, 1) / 0.02)
        field = prior(np.clip(U, 0, 1) * enabled, kp) + rng.normal(0, 0.3, len(kp))
        if mode in ('full', 'curve'):
            history = [PastIteration(np.where(enabled, rng.uniform(0, .6, 7), 0), prior(rng.uniform(0, .6, 7) * enabled, kp),
                                     None, {'radius': rng.uniform(0.01, 0.65)}) for _ in range(trial % 4)]
            # the curve is bent only on commissioning maps across the command range
            maps = [PastIteration(V, prior(V, kp) * rng.uniform(0.8, 1.2), None, {})
                    for V in rng.uniform(0, 1, (4, 7))] if mode == 'curve' else []
            step = rule.step(_inputs(rig, prior, U, field, target, history, k=len(history), enabled=enabled,
                                     prior_maps=maps))
            bent += bool(step.info['curve'])
        else:
            J = prior.jacobian(U, kp) * rng.uniform(0.01, 10)
            step = rule.step(UpdateInput(trial, U, target - field, J, enabled, None))
        out = step.U_next
        assert np.all(np.isfinite(out))
        assert np.all(out[enabled] >= 0.05 - 1e-12) and np.all(out[enabled] <= 0.6 + 1e-12)
        assert np.all(out[~enabled] == 0.0)
    assert (bent > 0) == (mode == 'curve')   # the curve mode did bend the curves


def test_a_disabled_fan_takes_no_part_even_if_the_model_wants_it(rig, prior):
    kp = rig.key_points
    off = rig.fans.with_disabled(['CM']).enabled
    target = prior(np.array([.3, .3, .3, .3, .3, .3, .6]), kp)  # needs the central fan
    U = np.where(off, 0.3, 0.0)
    step = AdaptiveUpdate().step(_inputs(rig, prior, U, prior(U, kp), target, enabled=off))
    assert step.U_next[6] == 0.0


# -- the bounded step ---------------------------------------------------------------------------
def test_on_a_linear_problem_one_step_is_the_bounded_least_squares_optimum(rng):
    n, N = 5, 60
    J = rng.normal(size=(N, n))
    U = np.full(n, 0.3)
    delta = rng.normal(size=N) * 3
    bounds = CommandBounds(0.0, 0.65)
    rule = AdaptiveUpdate(bounds=bounds, radius=0.65, damping=0.0, secant=False)
    step = rule.step(UpdateInput(0, U, delta, J, np.ones(n, bool)))
    best = lsq_linear(J, delta, bounds=(0 - U, 0.65 - U)).x + U
    np.testing.assert_allclose(step.U_next, best, atol=1e-6)
    assert np.any(np.isclose(step.U_next, 0.0)) or np.any(np.isclose(step.U_next, 0.65))  # active bound
    # clipping the unconstrained step (the paper's way) lands elsewhere, with a larger error
    clipped = np.clip(U + np.linalg.lstsq(J, delta, rcond=None)[0], 0, 0.65)
    assert np.linalg.norm(J @ (clipped - U) - delta) > np.linalg.norm(J @ (step.U_next - U) - delta)


def test_box_qp_matches_a_reference_bounded_least_squares_solver(rng):
    from wind_shaper.control import box_qp
    for _ in range(30):
        n = rng.integers(1, 12)
        A = rng.normal(size=(40, n)) * rng.uniform(0.01, 10, n)
        b = rng.normal(size=40) * 5
        lb = rng.uniform(-1, 0, n)
        ub = lb + rng.uniform(0, 1, n)
        x = box_qp(A.T @ A, -A.T @ b, lb, ub)
        ref = lsq_linear(A, b, bounds=(lb, ub), method='bvls', tol=1e-12).x
        assert np.all((x >= lb) & (x <= ub))
        assert np.sum((A @ x - b) ** 2) <= np.sum((A @ ref - b) ** 2) * (1 + 1e-9) + 1e-12


def test_the_trust_radius_limits_the_first_step(rng):
    J = rng.normal(size=(40, 3))
    step = AdaptiveUpdate(radius=0.05).step(UpdateInput(0, np.full(3, .3), 50 * rng.normal(size=40), J, np.ones(3, bool)))
    assert np.max(np.abs(step.U_next - 0.3)) <= 0.05 + 1e-12


def test_a_fan_idling_at_zero_comes_back_when_the_target_needs_it(rig, prior):
    # da/dU = 0 at U = 0 for a quadratic thrust curve: a Gauss-Newton step alone cannot lift it
    kp = rig.key_points
    U_star = np.array([0.4, 0.3, 0.35, 0.3, 0.4, 0.3, 0.0])
    U = U_star.copy()
    U[0] = 0.0
    target = prior(U_star, kp)
    step = AdaptiveUpdate(radius=0.5).step(_inputs(rig, prior, U, prior(U, kp), target))
    assert step.U_next[0] == pytest.approx(0.4, abs=0.02)


def test_a_failed_step_shrinks_the_radius_and_restarts_from_the_best_point(rig, prior):
    kp = rig.key_points
    target = prior(np.full(7, 0.4), kp)
    U0, U1 = np.full(7, 0.3), np.full(7, 0.6)
    info0 = {'radius': 0.4, 'predicted_error': 0.0, 'base_error': float(np.mean((prior(U0, kp) - target) ** 2)),
             'base_k': 0}
    history = [PastIteration(U0, prior(U0, kp), None, info0)]
    worse = prior(U1, kp) + 3.0  # the step made things much worse than predicted
    step = AdaptiveUpdate().step(_inputs(rig, prior, U1, worse, target, history, k=1))
    assert step.info['base_k'] == 0 and step.info['rho'] < 0
    assert step.info['radius'] < 0.4
    assert np.max(np.abs(step.U_next - U0)) <= step.info['radius'] + 1e-12


# -- the secant correction ----------------------------------------------------------------------
def test_multi_secant_recovers_a_known_linear_jacobian(rng):
    N, n = 80, 6
    A = rng.normal(size=(N, n))                  # the true Jacobian
    J0 = A + 0.5 * rng.normal(size=(N, n))       # a wrong prior
    S = rng.normal(scale=0.1, size=(n, n))       # n independent steps
    Y = S @ A.T                                  # measured changes (m, N)
    misses = Y - S @ J0.T                        # what the prior did not predict
    D = SecantCorrection(ridge=1e-12, min_step=0.0, memory=n).fit(S, misses)
    np.testing.assert_allclose(J0 + D.matrix(), A, atol=1e-8)
    v = rng.normal(size=n)
    np.testing.assert_allclose(D.matvec(v), D.matrix() @ v, atol=1e-12)
    w = rng.normal(size=N)
    np.testing.assert_allclose(D.rmatvec(w), D.matrix().T @ w, atol=1e-12)


def test_secant_with_fewer_pairs_is_exact_along_the_steps_and_zero_across(rng):
    N, n = 50, 5
    A, J0 = rng.normal(size=(N, n)), rng.normal(size=(N, n))
    S = rng.normal(scale=0.1, size=(2, n))
    D = SecantCorrection(ridge=1e-12, min_step=0.0).fit(S, S @ (A - J0).T)
    np.testing.assert_allclose((J0 + D.matrix()) @ S.T, A @ S.T, atol=1e-8)  # the secant condition
    across = np.linalg.svd(S)[2][-1]                                        # a direction no step took
    np.testing.assert_allclose(D.matvec(across), 0.0, atol=1e-8)            # least change


def test_secant_safeguards_small_steps_ridge_and_memory(rng):
    S = np.array([[0.001, 0.0], [0.2, 0.0], [0.0, 0.3], [0.1, 0.1]])
    R = rng.normal(size=(4, 10))
    D = SecantCorrection(ridge=0.0, min_step=0.01, memory=2).fit(S, R)
    assert D.n_pairs_ == 2                                   # tiny step dropped, oldest beyond memory dropped
    np.testing.assert_allclose(D.matvec(S[3]), R[3], atol=1e-10)
    shrunk = SecantCorrection(ridge=10.0, min_step=0.0).fit(S, R)
    assert np.linalg.norm(shrunk.matrix()) < 0.1 * np.linalg.norm(SecantCorrection(ridge=0.0, min_step=0.0).fit(S, R).matrix())
    with pytest.raises(ConfigError, match='ridge'):
        SecantCorrection(ridge=-1)
    empty = SecantCorrection(min_step=1.0).fit(S, R)
    assert empty.n_pairs_ == 0 and np.all(empty.matrix() == 0)


def test_broyden_update_satisfies_the_secant_condition(rng):
    J, s, y = rng.normal(size=(20, 4)), rng.normal(size=4), rng.normal(size=20)
    J1 = broyden_update(J, s, y)
    np.testing.assert_allclose(J1 @ s, y, atol=1e-12)
    t = np.linalg.svd(s[None])[2][-1]
    np.testing.assert_allclose(J1 @ t, J @ t, atol=1e-12)
    np.testing.assert_array_equal(broyden_update(J, np.zeros(4), y), J)


def test_the_rule_learns_a_linear_plant_the_prior_gets_wrong(rng):
    # Jacobian-only mode: the plant is linear with Jacobian A, the rule is told J0 each time
    N, n = 120, 4
    A = rng.normal(size=(N, n))
    J0 = A * rng.uniform(0.5, 1.5, n) + 0.3 * rng.normal(size=(N, n))
    target = A @ np.array([0.3, 0.4, 0.2, 0.5]) + 0.2 * rng.normal(size=N)
    rule = AdaptiveUpdate(secant_min_step=0.0, damping=0.0)
    best = lsq_linear(A, target, bounds=(0, 0.65)).x
    U, history = np.full(n, 0.1), []
    for k in range(12):
        field = A @ U
        step = rule.step(UpdateInput(k, U, target - field, J0, np.ones(n, bool), None, target=target,
                                     history=tuple(history)))
        history.append(PastIteration(U, field, None, step.info))
        U = step.U_next
    err = np.mean((A @ U - target) ** 2)
    assert err <= 1.02 * np.mean((A @ best - target) ** 2)


# -- the per-fan factorisation and fit ------------------------------------------------------------
@pytest.mark.parametrize('sparse', [False, True])
def test_fan_basis_reproduces_the_prior(rig, prior, rng, sparse):
    basis = FanBasis.from_term(prior, rig.key_points, sparse=sparse)
    atol = 5e-3 if sparse else 1e-9  # a sparse basis drops footprint values below 1e-4 of the peak
    for _ in range(3):
        U = rng.uniform(0, 0.8, 7)
        a, da = basis.thrust(U)
        np.testing.assert_allclose(basis.offset + basis.shape @ a, prior(U, rig.key_points), atol=atol)
        np.testing.assert_allclose(basis.shape @ np.diag(da), prior.jacobian(U, rig.key_points), atol=atol)
    assert basis.monotone
    t = basis.thrust(np.full(7, 0.37))[0]
    np.testing.assert_allclose(basis.invert(t, np.zeros(7), np.ones(7)), 0.37, atol=1e-7)


def test_fan_basis_inverts_many_thrusts_at_once_as_it_inverts_each(rig, prior, rng):
    # the ridge test inverts 19 thrust vectors per step in one batch; each row must come out
    # as it does alone (its own stop), including thrusts beyond [a(lo), a(hi)], which clip
    basis = FanBasis.from_term(prior, rig.key_points)
    lo, hi = np.full(7, 0.1), np.full(7, 0.7)
    a_lo, a_hi = basis.thrust(lo)[0], basis.thrust(hi)[0]
    rows = a_lo + rng.uniform(-0.2, 1.2, (25, 7)) * (a_hi - a_lo)
    batched = basis.invert(rows, lo, hi)
    alone = np.array([basis.invert(t, lo, hi) for t in rows])
    np.testing.assert_array_equal(batched, alone)
    assert np.all((batched >= lo) & (batched <= hi))
    inside = (rows > a_lo) & (rows < a_hi)
    np.testing.assert_allclose(np.array([basis.thrust(u)[0] for u in batched])[inside], rows[inside], rtol=1e-7)
    np.testing.assert_array_equal(batched[rows <= a_lo], np.broadcast_to(lo, rows.shape)[rows <= a_lo])


def test_fan_basis_refuses_a_prior_whose_fans_do_not_superpose(rig):
    jets = FanJets(rig.fans, **JETS)
    with pytest.raises(ConfigError, match='superpose'):
        FanBasis.from_term(jets * jets, rig.key_points)


def test_shape_fit_recovers_a_weak_fan_and_a_shifted_jet(rig, prior, rng):
    kp = rig.key_points
    basis = FanBasis.from_term(prior, kp)
    fit = ShapeFit(noise_std=0.01)
    truth = fit.prior(7)[0].copy()
    truth[1 + 3] = 0.8            # gain of HM2
    truth[1 + 7 + 0] = 0.015      # LM1's jet lands 1.5 cm towards +x
    S = fit.shape_matrix(basis, truth)
    maps = []
    for _ in range(3):
        U = rng.uniform(0.2, 0.6, 7)
        maps.append((U, basis.offset + S @ basis.thrust(U)[0] + 0.01 * rng.normal(size=len(kp)), np.ones(len(kp))))
    theta = fit.fit(basis, maps, rig.fans.enabled)
    assert theta[1 + 3] == pytest.approx(0.8, abs=0.01)
    assert theta[1 + 7 + 0] == pytest.approx(0.015, abs=0.002)


def test_shape_fit_prior_mean_holds_where_the_maps_say_nothing(rig, prior, rng):
    """A fan idle in every map keeps the gain of the prior mean it is given; the same maps with
    another prior mean give another fit (the normal equations' cache is keyed by it too)."""
    basis = FanBasis.from_term(prior, rig.key_points)
    plain = ShapeFit(noise_std=0.05)
    mean = plain.prior(7)[0].copy()
    mean[1 + 6] = 0.6             # the central fan's gain, as the commissioning taught it
    mean[1 + 3] = 0.7             # HM2's: the maps show it at 1
    told = ShapeFit(noise_std=0.05, prior_mean=tuple(mean))
    maps = []
    for _ in range(2):
        U = np.r_[rng.uniform(0.2, 0.6, 6), 0.0]          # the central fan idle
        maps.append((U, basis.offset + basis.shape @ basis.thrust(U)[0], np.ones(len(rig.key_points))))
    first, second = plain.fit(basis, maps, rig.fans.enabled), told.fit(basis, maps, rig.fans.enabled)
    assert first[1 + 6] == pytest.approx(1.0) and second[1 + 6] == pytest.approx(0.6)
    assert first[1 + 3] == pytest.approx(1.0, abs=0.02) and second[1 + 3] == pytest.approx(1.0, abs=0.02)


def test_sparse_jacobian_equals_the_dense_one_on_a_wall(rng):
    fans = FanArray.grid(16, 16, 0.08)
    kp = rect_key_points(0.64, 0.64, 30, 30)
    term = paper_prior(fans)
    U = rng.uniform(0, 0.65, fans.n_fans)
    np.testing.assert_allclose(term.sparse_jacobian(U, kp, tol=1e-12).toarray(), term.jacobian(U, kp), atol=1e-10)
    loose = term.sparse_jacobian(U, kp, tol=1e-3)
    assert loose.nnz < 0.5 * kp.shape[0] * fans.n_fans
    np.testing.assert_allclose(loose.toarray(), term.jacobian(U, kp), atol=2e-3 * np.abs(term.jacobian(U, kp)).max())


def test_the_wall_path_keeps_bounds_and_improves_a_reachable_target(rng):
    fans = FanArray.grid(10, 10, 0.08).with_disabled(['F00_00', 'F05_05'])
    kp = rect_key_points(0.4, 0.4, 30, 30)
    geo = TunnelGeometry(fans, kp)
    term = paper_prior(fans)
    U_star = np.where(fans.enabled, rng.uniform(0.2, 0.5, fans.n_fans), 0.0)
    target = term(U_star, kp)
    basis = FanBasis.from_term(term, kp, sparse=True)
    rule = AdaptiveUpdate()
    U, history = np.where(fans.enabled, 0.3, 0.0), []
    from wind_shaper.control import adaptive as solvers
    solvers._BASIS_CACHE.clear()
    solvers._BASIS_CACHE[(id(term), kp.shape, float(np.sum(kp)))] = (term, basis)  # force the sparse path
    errors = []
    for k in range(4):
        field = term(U, kp)
        errors.append(np.mean((field - target) ** 2))
        step = rule.step(UpdateInput(k, U, target - field, None, fans.enabled, None, model=term,
                                     key_points=geo.key_points, target=target, history=tuple(history)))
        assert step.info['mode'] in ('prior', 'gain')
        history.append(PastIteration(U, field, None, step.info))
        U = step.U_next
        assert np.all((U >= 0) & (U <= 0.65)) and np.all(U[~fans.enabled] == 0)
    solvers._BASIS_CACHE.clear()
    assert np.mean((term(U, kp) - target) ** 2) < 0.05 * errors[0]


# -- the stopping rule ----------------------------------------------------------------------------
def test_stopping_rule_compares_predicted_gain_with_the_estimate_noise():
    rule = StoppingRule(factor=1.0, floor=0.1, patience=2, min_iterations=2)
    std = np.full(10, 0.1)  # noise = 0.01 + 0.01 = 0.02 N^2
    assert rule.noise(std) == pytest.approx(0.02)
    assert rule.quiet(0.01, std) and not rule.quiet(0.05, std)
    quiet = PastIteration(np.zeros(2), np.zeros(10), None, {'quiet': True})
    loud = PastIteration(np.zeros(2), np.zeros(10), None, {'quiet': False})
    assert rule(5, 0.01, std, [loud, quiet])[0]            # two quiet in a row
    assert not rule(5, 0.01, std, [quiet, loud])[0]        # only one
    assert not rule(0, 0.0, std, [quiet] * 3)[0]           # never before min_iterations
    assert not rule(5, 0.05, std, [quiet] * 3)[0]


def test_stopping_rule_fires_on_a_converged_run_and_not_on_a_fresh_one(rig, prior):
    """On a tunnel that is the model (plus sweep noise) the run converges in a few iterations."""
    from test_calibration_and_loop import ModelPlant
    plant = ModelPlant(rig, prior, noise=0.05, seed=3)
    kp = rig.key_points
    # 7 fans cannot make the ripple: the best reachable error is well above zero
    target = prior(np.array([0.45, 0.3, 0.5, 0.35, 0.4, 0.3, 0.1]), kp) + 0.4 * np.cos(25 * kp[:, 0])
    loop = ShapingLoop(plant, prior, target, AdaptiveUpdate(), FieldEstimator(), u0=0.5,
                       truth=lambda U: prior(U, kp))
    history = loop.run(8)
    flags = [r.info.get('stop') for r in history[:-1]]
    assert flags[0] is False and flags[1] is False           # a fresh run: far from done
    first = flags.index(True)                                # it does fire ...
    errors = [r.true_error for r in history]
    assert errors[first + 1] <= 1.05 * min(errors)           # ... once little is left to gain
    stopped = ShapingLoop(ModelPlant(rig, prior, noise=0.05, seed=3), prior, target, AdaptiveUpdate(),
                          FieldEstimator(), u0=0.5).run(8, stop_early=True)
    assert len(stopped) == first + 2 and stopped[-1].next_pwm is None


# -- configuration ----------------------------------------------------------------------------------
def test_make_rule_builds_both_methods_from_one_section():
    cfg = ShapingConfig(update={'method': 'adaptive', 'gain': 0.8, 'rcond': 1e-3, 'radius': 0.3})
    rule = cfg.make_rule()
    assert isinstance(rule, AdaptiveUpdate) and rule.radius == 0.3 and rule.step_fraction == 1.0
    assert cfg.make_rule(gain=0.5).step_fraction == 0.5           # CLI --gain: fraction of the step
    paper = cfg.make_rule(method='paper')
    assert isinstance(paper, PaperUpdate) and paper.gain == 0.8 and paper.rcond == 1e-3
    with pytest.raises(ConfigError, match='bogus'):
        ShapingConfig(update={'method': 'adaptive', 'bogus': 1}).make_rule()
    with pytest.raises(ConfigError, match='adaptive or paper'):
        ShapingConfig(update={'method': 'newton'}).make_rule()
    with pytest.raises(ConfigError, match='radii'):
        AdaptiveUpdate(radius=0.0)


# -- estimation for large walls ------------------------------------------------------------------
def _smooth(P):
    return 3.0 + 1.5 * np.exp(-((P[:, 0] - 0.1) ** 2 + (P[:, 1] + 0.05) ** 2) / 0.03) + 4.0 * (P ** 2).sum(1)


def test_local_gp_agrees_with_the_exact_gp(rng):
    P = rng.uniform(-0.5, 0.5, (900, 2))
    F = _smooth(P) + 0.1 * rng.normal(size=900)
    Q = rect_key_points(0.45, 0.45, 30, 30)
    exact_mean, exact_std = GaussianProcessField(0.1, 0.1).fit(P, F).predict(Q, True)
    local_mean, local_std = LocalGaussianProcessField(0.1, 0.1, block=0.2, halo=0.2).fit(P, F).predict(Q, True)
    assert np.sqrt(np.mean((local_mean - exact_mean) ** 2)) < 0.01
    assert np.max(np.abs(local_std - exact_std)) < 0.01
    assert FieldEstimator(noise_model='white').make_gp(5000).__class__ is LocalGaussianProcessField
    assert FieldEstimator().make_gp(5000).__class__ is LocalTurbulentGaussianProcessField
    assert FieldEstimator(noise_model='white').make_gp(500).__class__ is GaussianProcessField
    assert FieldEstimator().make_gp(500).__class__ is TurbulentGaussianProcessField
    with pytest.raises(ConfigError, match='auto, exact or local'):
        FieldEstimator(method='fast')


def test_gp_hyperparameters_are_estimated_inside_their_bounds(rng):
    P = rng.uniform(-0.4, 0.4, (300, 2))
    F = _smooth(P) + 0.2 * rng.normal(size=300)
    hp = fit_hyperparameters(P, F)
    assert hp['noise_std'] == pytest.approx(0.2, rel=0.3)
    tight = fit_hyperparameters(P, F, noise_std_bounds=(0.01, 0.05), length_scale_bounds=(0.2, 0.25))
    assert tight['noise_std'] <= 0.05 + 1e-9 and 0.2 - 1e-9 <= tight['length_scale'] <= 0.25 + 1e-9
    gp = GaussianProcessField(hp['length_scale'], hp['noise_std'], hp['signal_std']).fit(P, F)
    worse = GaussianProcessField(0.1, 0.01).fit(P, F)
    assert gp.log_marginal_likelihood() > worse.log_marginal_likelihood()


# -- pooling the maps near the base ---------------------------------------------------------------
def test_two_sweeps_at_the_same_commands_are_averaged_before_the_step(rig, prior):
    """Noise +e in one sweep and -e in the next at the same commands: the pooled step is the
    step the noise-free field gives; with pooling off it follows the last sweep's noise."""
    kp = rig.key_points
    U_star = np.array([0.45, 0.35, 0.4, 0.3, 0.42, 0.33, 0.2])
    U = U_star + 0.04
    field, target = prior(U, kp), prior(U_star, kp)
    # sweep noise is smooth in space (a GP estimate): here it looks like LM2 running 0.05 high
    e = prior(U + np.array([0, 0, 0.05, 0, 0, 0, 0]), kp) - field
    history = [PastIteration(U, field + e, None, {})]

    def step(pool_within, noisy=True, past=history):
        rule = AdaptiveUpdate(correction='none', relearn=False, pool_within=pool_within)
        return rule.step(_inputs(rig, prior, U, field - e if noisy else field, target, past, k=len(past)))

    clean = step(0.05, noisy=False, past=())
    pooled, alone = step(0.05), step(0.0)
    assert pooled.info['pooled_maps'] == 2 and alone.info['pooled_maps'] == 1
    np.testing.assert_allclose(pooled.U_next, clean.U_next, atol=1e-6)
    assert np.max(np.abs(alone.U_next - clean.U_next)) > 0.03


def test_a_map_farther_than_pool_within_is_not_averaged_in(rig, prior):
    kp = rig.key_points
    U = np.full(7, 0.4)
    far = U + np.array([0.06, 0, 0, 0, 0, 0, 0])
    target = prior(np.full(7, 0.35), kp)
    history = [PastIteration(far, prior(far, kp) + 0.3, None, {})]
    step = AdaptiveUpdate(correction='none', relearn=False, pool_within=0.05).step(
        _inputs(rig, prior, U, prior(U, kp), target, history, k=1))
    assert step.info['pooled_maps'] == 1


def test_pool_within_outside_its_range_is_refused():
    with pytest.raises(ConfigError, match='pool_within'):
        AdaptiveUpdate(pool_within=-0.1)


def test_shape_fit_learns_a_stall_dip_in_one_fans_curve(rig, prior, rng):
    """A dip of 40 % around 35 % PWM in HM2's curve, which no gain can hold: with the curve
    correction the fit over maps at scattered commands finds HM2's gain in the dip and out of
    it (gain_j + h_j(u)), leaves the other fans' alone, and predicts a new map far better than
    without."""
    kp = rig.key_points
    basis = FanBasis.from_term(prior, kp)

    def dip(U):
        return 1.0 - 0.4 * np.exp(-((U[3] - 0.35) / 0.08) ** 2)

    def field(U):
        a = basis.thrust(U)[0].copy()
        a[3] *= dip(U)
        return basis.offset + basis.shape @ a

    maps = []
    for _ in range(12):
        U = rng.uniform(0.1, 0.8, 7)
        maps.append((U, field(U) + 0.01 * rng.normal(size=len(kp)), np.ones(len(kp))))
    curved, plain = ShapeFit(noise_std=0.01, curve_sd=0.3), ShapeFit(noise_std=0.01)
    theta, flat = curved.fit(basis, maps, rig.fans.enabled), plain.fit(basis, maps, rig.fans.enabled)

    def gain(u, fan=3):
        U = np.full(7, 0.5)
        U[fan] = u
        return theta[1 + fan] + curved.curve(theta, U, 7)[0][fan]

    assert gain(0.35) == pytest.approx(0.6, abs=0.05)
    assert gain(0.3) == pytest.approx(0.73, abs=0.05)
    assert gain(0.7) == pytest.approx(1.0, abs=0.05)
    assert all(gain(u, fan=0) == pytest.approx(1.0, abs=0.05) for u in (0.2, 0.35, 0.6))

    def predict(fit, th, U):
        a = basis.thrust(U)[0]
        h = fit.curve(th, U, 7)[0]
        return fit.shape_matrix(basis, th) @ a + th[0] + basis.offset + basis.shape @ (a * h)

    U = np.array([0.4, 0.3, 0.5, 0.33, 0.45, 0.3, 0.2])        # HM2 in its dip
    err_curved = np.sqrt(np.mean((predict(curved, theta, U) - field(U)) ** 2))
    err_plain = np.sqrt(np.mean((predict(plain, flat, U) - field(U)) ** 2))
    assert err_curved < 0.5 * err_plain
    assert curved.fit(basis, maps, rig.fans.enabled).shape == (len(flat) + 70,)


def test_the_curve_is_bent_only_while_the_commissioning_maps_are_in_the_fit(rig, prior, rng):
    """The run's own maps sit close together, where a bend in a fan's curve and its gain look
    alike: without commissioning maps, or once the run has relearned, the fit keeps the gains."""
    kp = rig.key_points
    rule = AdaptiveUpdate(curve_sd=0.07)
    target = prior(np.full(7, 0.4), kp)
    U = np.full(7, 0.45)
    maps = [PastIteration(V, prior(V, kp), None, {}) for V in rng.uniform(0, 1, (4, 7))]
    history = [PastIteration(np.full(7, 0.5), prior(np.full(7, 0.5), kp), None, {'radius': 0.35})]
    with_maps = rule.step(_inputs(rig, prior, U, prior(U, kp), target, history, k=1, prior_maps=maps))
    assert with_maps.info['curve']
    assert not rule.step(_inputs(rig, prior, U, prior(U, kp), target, history, k=1)).info['curve']
    contradicted = [PastIteration(history[0].U, history[0].mean, None,
                                  {'radius': 0.35, 'warm_start': {'check': {'mismatch': True}}})]
    assert not rule.step(_inputs(rig, prior, U, prior(U, kp), target, contradicted, k=1,
                                 prior_maps=maps)).info['curve']
    assert not AdaptiveUpdate(curve_sd=0.0).step(
        _inputs(rig, prior, U, prior(U, kp), target, history, k=1, prior_maps=maps)).info['curve']


def test_a_curve_sd_outside_its_range_is_refused():
    with pytest.raises(ConfigError, match='curve_sd'):
        AdaptiveUpdate(curve_sd=2.0)


def _maps_running(rig, prior, rng, fan, high, n=8):
    """Commissioning-like maps with every fan across 0.1-0.9 but ``fan`` only up to ``high``."""
    out = []
    for _ in range(n):
        V = rng.uniform(0.1, 0.9, 7)
        V[fan] = rng.uniform(0.05, high)
        out.append(PastIteration(V, prior(V, rig.key_points), None, {}))
    return out


def _curve_fit(rig, prior, high, seed=3):
    basis = FanBasis.from_term(prior, rig.key_points)
    fit = ShapeFit(noise_std=0.1, curve_sd=0.07)
    maps = [(p.U, p.mean, np.full(len(rig.key_points), 0.5))
            for p in _maps_running(rig, prior, np.random.default_rng(seed), 3, high)]
    theta, cov = fit.fit_posterior(basis, maps, rig.fans.enabled)
    assert np.allclose(theta, fit.fit(basis, maps, rig.fans.enabled))
    return basis, fit, fit.curve_cov(cov, 7)


def test_the_curve_posterior_is_narrow_only_where_the_maps_ran_the_fan(rig, prior):
    """A gain change shows in the field in proportion to the fan's thrust, so the maps pin a
    curve down where they ran the fan hard; where none did, it keeps about the prior's spread."""
    def sd(C, fan, u):   # the posterior sd of the fan's curve correction h(u)
        phi = ShapeFit.bumps(np.full(7, u))[0][:, fan]
        return float(np.sqrt(phi @ C[fan] @ phi))

    _, _, seen = _curve_fit(rig, prior, 0.95)
    _, _, unseen = _curve_fit(rig, prior, 0.4)
    prior_sd = 0.07 * float(np.linalg.norm(ShapeFit.bumps(np.full(7, 0.8))[0][:, 3]))
    assert sd(unseen, 3, 0.8) > 0.8 * prior_sd
    assert sd(seen, 3, 0.8) < 0.75 * sd(unseen, 3, 0.8)
    assert sd(unseen, 0, 0.8) < 0.75 * sd(unseen, 3, 0.8)   # the other fans ran there


def test_the_curve_risk_grows_with_a_move_where_no_map_has_been_and_matches_its_derivatives(rig, prior):
    from wind_shaper.control.adaptive import _CurveRisk
    U_b = np.full(7, 0.4)
    risks = {}
    for high in (0.4, 0.95):
        basis, _, curve_cov = _curve_fit(rig, prior, high)
        risks[high] = _CurveRisk(basis, curve_cov, U_b, np.ones(len(rig.key_points)))

    def moved(fan, du):
        U = U_b.copy()
        U[fan] += du
        return U

    risk = risks[0.4]
    assert risk(U_b)[0] == pytest.approx(0.0, abs=1e-15)
    assert 0 < risk(moved(3, 0.2))[0] < risk(moved(3, 0.4))[0]
    # the same move where the maps did run the fan costs far less
    assert risks[0.95](moved(3, 0.4))[0] < 0.5 * risk(moved(3, 0.4))[0]
    assert risk(moved(0, 0.4))[0] < 0.5 * risk(moved(3, 0.4))[0]
    # the per-fan curvature and slope of the Gauss-Newton model against finite differences
    _, h, g = risk(moved(3, 0.2))
    for fan in (0, 3):
        e = 1e-5
        up = risk(moved(fan, 0.2 * (fan == 3) + e))[0]
        down = risk(moved(fan, 0.2 * (fan == 3) - e))[0]
        assert (up - down) / (2 * e) == pytest.approx(2 * g[fan], rel=1e-3, abs=1e-9)
        assert h[fan] > 0


def test_with_curve_risk_a_step_into_a_curve_no_map_has_pinned_down_is_shorter(rig, prior):
    """The same step asked of a fan whose curve the maps show there, and of one whose curve they
    do not: the risk shortens the second more."""
    kp = rig.key_points
    U = np.full(7, 0.4)
    history = [PastIteration(np.full(7, 0.42), prior(np.full(7, 0.42), kp), None, {'radius': 0.35})]
    Ut = U.copy()
    Ut[3] = 0.6
    target = prior(Ut, kp)
    shrink = {}
    for high in (0.4, 0.95):
        maps = _maps_running(rig, prior, np.random.default_rng(3), 3, high)
        move = {}
        for r in (0.0, 10.0):
            step = AdaptiveUpdate(curve_sd=0.07, curve_risk=r).step(
                _inputs(rig, prior, U, prior(U, kp), target, history, k=1, prior_maps=maps))
            assert step.info['curve']
            move[r] = step.U_next[3] - U[3]
        assert move[0.0] > 0.15                      # without the risk: most of the way
        shrink[high] = move[10.0] / move[0.0]
    assert shrink[0.4] < 0.85 and shrink[0.4] < shrink[0.95] - 0.04, shrink


def test_a_curve_risk_outside_its_range_is_refused():
    with pytest.raises(ConfigError, match='curve_risk'):
        AdaptiveUpdate(curve_risk=-1.0)


def test_the_way_between_two_commands_is_straight_in_the_fans_thrusts(rig, prior):
    from wind_shaper.control.adaptive import _path
    basis = FanBasis.from_term(prior, rig.key_points)
    U0, U1 = np.full(7, 0.2), np.array([0.6, 0.1, 0.5, 0.35, 0.2, 0.8, 0.05])
    Us, f = _path(lambda U: float(np.sum(U)), U0, U1, basis, points=11)
    assert np.array_equal(Us[0], U0) and np.array_equal(Us[-1], U1) and len(f) == 11
    a0, a1 = basis.thrust(U0)[0], basis.thrust(U1)[0]
    for t, U in zip(np.linspace(0, 1, 11), Us):
        assert basis.thrust(U)[0] == pytest.approx(a0 + t * (a1 - a0), abs=1e-6)
    straight, _ = _path(lambda U: 0.0, U0, U1, points=3)
    assert straight[1] == pytest.approx(0.5 * (U0 + U1))
    # a fan's thrust is not linear in its command: the two ways differ between the ends
    assert not np.allclose(Us[5], 0.5 * (U0 + U1), atol=1e-3)


def _bumpy(height, end):
    """An objective along U[0] from 0 to 1: 1 at 0, ``end`` at 1, and a bump of ``height``
    above the straight line at 0.5."""
    return lambda U: float(1.0 + (end - 1.0) * U[0] + height * np.exp(-((U[0] - 0.5) / 0.1) ** 2))


def test_a_ridge_is_a_rise_on_the_way_beyond_what_its_end_promises():
    from wind_shaper.control.adaptive import _before_ridge, _ridge
    U0, U1 = np.zeros(2), np.array([1.0, 0.0])
    assert _ridge(_bumpy(0.0, 0.5), U0, U1, 0.1, 0.0) is None            # downhill all the way
    assert _ridge(_bumpy(0.05, 0.5), U0, U1, 0.1, 0.0) is None           # a rise within the share
    ridge = _ridge(_bumpy(1.0, 0.8), U0, U1, 0.1, 0.0)
    assert ridge['t'] == pytest.approx(0.5) and ridge['start'] == pytest.approx(1.0)
    assert ridge['height'] == pytest.approx(1.9, abs=0.01) and ridge['end'] == pytest.approx(0.8)
    assert _ridge(_bumpy(1.0, 0.8), U0, U1, 0.1, 1.0) is None            # within the noise
    # a rise smaller than what the far end gains is crossed: a wrong basin is left that way
    assert _ridge(_bumpy(0.7, 0.05), U0, U1, 0.1, 0.0) is None
    # cut back: the best point before the way first rises past the share
    dip_then_ridge = lambda U: float(1.0 - 0.3 * np.sin(np.pi * U[0] / 0.4) * (U[0] < 0.4)
                                     + 2.0 * np.exp(-((U[0] - 0.6) / 0.1) ** 2))
    assert _before_ridge(dip_then_ridge, U0, U1, 0.1, 0.0) == pytest.approx([0.2, 0.0])
    assert np.array_equal(_before_ridge(_bumpy(0.0, 0.5), U0, U1, 0.1, 0.0), U1)


def test_a_ridge_share_outside_its_range_is_refused():
    with pytest.raises(ConfigError, match='ridge_share'):
        AdaptiveUpdate(ridge_share=-0.1)


def _maps_at_scattered_loads(basis, field, rng, n=6):
    maps = []
    for _ in range(n):
        U = rng.uniform(0.1, 0.6, 7)
        maps.append((U, field(U) + 0.01 * rng.normal(size=len(basis.key_points)), np.ones(len(basis.key_points))))
    return maps


def test_shape_fit_learns_a_share_of_the_jets_spread_over_the_section(rig, prior, rng):
    """A fifth of every fan's force at the key points lands spread evenly over them (a mesh
    screen): with the spread term the fit finds the share and leaves the gains at 1, and predicts
    a new map to the noise; without it the gains take up the misfit (the central fan's most) and
    a new map is off by a tenth of a newton."""
    basis = FanBasis.from_term(prior, rig.key_points)
    m = basis.shape_means

    def field(U):
        a = basis.thrust(U)[0]
        return basis.offset + basis.shape @ a + 0.2 * float(m @ a)

    maps = _maps_at_scattered_loads(basis, field, rng)
    spread, plain = ShapeFit(noise_std=0.01, spread_sd=0.3), ShapeFit(noise_std=0.01)
    theta, flat = spread.fit(basis, maps, rig.fans.enabled), plain.fit(basis, maps, rig.fans.enabled)
    assert spread.spread_share(theta) == pytest.approx(0.2, abs=0.01)
    assert np.allclose(theta[1:8], 1.0, atol=0.01)
    assert abs(flat[1 + 6] - 1.0) > 0.05

    def error(fit, th, U):
        return np.sqrt(np.mean((basis.offset + th[0] + fit.shape_matrix(basis, th) @ basis.thrust(U)[0] - field(U)) ** 2))
    U = rng.uniform(0.1, 0.6, 7)
    assert error(spread, theta, U) < 0.01 and error(plain, flat, U) > 0.05


def test_shape_fit_holds_a_negative_spread_at_zero(rig, prior, rng):
    """Force spread over the section only adds to it: maps that would want a negative share
    (other misfit) get the fit without the term, not a share below 0."""
    basis = FanBasis.from_term(prior, rig.key_points)
    m = basis.shape_means

    def field(U):
        a = basis.thrust(U)[0]
        return basis.offset + basis.shape @ a - 0.2 * float(m @ a)

    maps = _maps_at_scattered_loads(basis, field, rng)
    spread, plain = ShapeFit(noise_std=0.01, spread_sd=0.3), ShapeFit(noise_std=0.01)
    theta = spread.fit(basis, maps, rig.fans.enabled)
    assert spread.spread_share(theta) == 0.0
    assert np.allclose(theta[:-1], plain.fit(basis, maps, rig.fans.enabled))


def test_a_plane_across_the_section_no_longer_bends_the_gains_and_the_load_slope(rig, prior, rng):
    """A warm wall's tilt (0.15 and -0.1 N per 0.1 m along x and y) over a starved inlet
    (slope -1): fitted as a plane it leaves each gain at 1 and finds the slope; without it the
    fans' shifts and gains take it up at each load and the slope comes out wrong by a fifth or
    more (-1.29 on these maps; -0.60 on another draw)."""
    from wind_shaper.control.shape_fit import LOAD_REF
    basis, on = FanBasis.from_term(prior, rig.key_points), rig.fans.enabled
    tilt = np.array([0.15, -0.1])

    def field(U):
        load = float(np.mean(U[on])) - LOAD_REF
        return basis.offset + (1.0 - 1.0 * load) * (basis.shape @ basis.thrust(U)[0]) + rig.key_points @ tilt / 0.1

    maps = _maps_at_scattered_loads(basis, field, rng)
    tilted, plain = ShapeFit(noise_std=0.01, load_sd=0.5, tilt_sd=0.3), ShapeFit(noise_std=0.01, load_sd=0.5)
    theta, flat = tilted.fit(basis, maps, on), plain.fit(basis, maps, on)
    assert tilted.load_slope(theta) == pytest.approx(-1.0, abs=0.03)
    assert theta[-2:] == pytest.approx(tilt, abs=0.01)
    assert np.allclose(theta[1:8], 1.0, atol=0.01)
    assert abs(plain.load_slope(flat) + 1.0) > 0.2 and np.max(np.abs(flat[1:8] - 1.0)) > 0.05


@pytest.mark.parametrize('name', ['spread_sd', 'tilt_sd'])
def test_a_spread_or_tilt_sd_outside_its_range_is_refused(name):
    with pytest.raises(ConfigError, match=name):
        AdaptiveUpdate(**{name: -0.1})


def test_a_step_takes_a_running_fan_half_way_down_unless_switching_it_off_clearly_pays(rig, prior):
    """The best field has fan 2 off; it runs at 0.12 PWM. Switched off, the step gains a sliver
    over the same step with the fan half way down, far less than one sweep's noise: with
    ``off_margin`` it goes half way, still running, and says so; with a margin that sliver
    clears, or with none, it goes off."""
    kp = rig.key_points
    U = np.full(7, 0.3)
    U[2] = 0.12
    off = U.copy()
    off[2] = 0.0
    target, field = prior(off, kp), prior(U, kp)
    steps = {m: AdaptiveUpdate(off_margin=m).step(_inputs(rig, prior, U, field, target)) for m in (0.0, 1.0, 1e-3)}
    assert steps[0.0].U_next[2] == 0.0 and steps[0.0].info['held_on'] == 0
    assert steps[1.0].U_next[2] == pytest.approx(0.06) and steps[1.0].info['held_on'] == 1
    assert steps[1e-3].U_next[2] == 0.0 and steps[1e-3].info['held_on'] == 0
    assert np.all(steps[1.0].U_next <= AdaptiveUpdate().bounds.u_max)


def test_an_off_margin_below_zero_is_refused():
    with pytest.raises(ConfigError, match='off_margin'):
        AdaptiveUpdate(off_margin=-1.0)


def _dip_maps(rig, basis, rng, depth, width=0.08, n=8, other=None):
    """n maps at scattered commands of a tunnel whose fans all dip around 0.3 PWM, each by its
    own depth (0: no dip), plus ``other(U)`` [N] at the key points when given."""
    def field(U):
        a = basis.thrust(U)[0] * (1.0 - depth * np.exp(-((U - 0.3) / width) ** 2))
        return basis.offset + basis.shape @ a + (0.0 if other is None else other(U))

    maps = []
    for _ in range(n):
        U = rng.uniform(0.05, 0.65, 7)
        maps.append((U, field(U) + 0.02 * rng.normal(size=len(rig.key_points)), np.ones(len(rig.key_points))))
    return maps, field


def _predict(basis, fit, theta, U):
    a = basis.thrust(U)[0]
    h = fit.curve(theta, U, 7)[0]
    return fit.shape_matrix(basis, theta) @ a + theta[0] + basis.offset + basis.shape @ (a * h)


def test_a_dip_every_fan_shares_is_learned_from_every_fans_maps(rig, prior, rng):
    """Fans of one make stall at the same command, each by its own depth: eight maps at
    scattered commands show each fan's curve at eight points only, too few to place a dip 0.08
    PWM wide fan by fan, but together they show it at 56. With the shared curve the fit
    predicts a map with every fan in the dip far better than with each fan's curve alone."""
    basis = FanBasis.from_term(prior, rig.key_points)
    maps, field = _dip_maps(rig, basis, rng, rng.uniform(0.25, 0.45, 7))
    U = np.array([0.3, 0.29, 0.31, 0.3, 0.28, 0.32, 0.3])      # every fan in the dip

    def miss(fit):
        theta = fit.fit(basis, maps, rig.fans.enabled)
        return float(np.sqrt(np.mean((_predict(basis, fit, theta, U) - field(U)) ** 2)))

    own = miss(ShapeFit(noise_std=0.05, curve_sd=0.07))
    assert miss(ShapeFit(noise_std=0.05, curve_sd=0.07, shared_curve_sd=0.1)) < 0.5 * own
    assert miss(ShapeFit(noise_std=0.05)) > 1.5 * own     # and each fan's own curve helps too


def test_the_shared_curve_stays_straight_where_the_maps_show_no_dip(rig, prior, rng):
    """Misfit of another kind (one fan weak, a draft across the section, its jets landing off
    their hubs) is not a dip every fan shares: the maps' evidence keeps the shared curve at 0,
    and the fit is the one without it."""
    basis = FanBasis.from_term(prior, rig.key_points)
    x, y = rig.key_points[:, 0], rig.key_points[:, 1]

    def other(U):
        a = basis.thrust(U)[0]
        return -0.3 * basis.shape[:, 2] * a[2] + 0.4 * basis.dx @ a + 0.5 * x + 0.3 * y

    maps, _ = _dip_maps(rig, basis, rng, np.zeros(7), other=other)
    shared = ShapeFit(noise_std=0.05, curve_sd=0.07, shared_curve_sd=0.1)
    theta = shared.fit(basis, maps, rig.fans.enabled)
    assert not shared.shared_curve_used(theta)
    own = ShapeFit(noise_std=0.05, curve_sd=0.07)
    np.testing.assert_allclose(shared.curve(theta, np.full(7, 0.3), 7)[0],
                               own.curve(own.fit(basis, maps, rig.fans.enabled), np.full(7, 0.3), 7)[0], atol=1e-9)
    dipped, _ = _dip_maps(rig, basis, np.random.default_rng(5), np.full(7, 0.35), other=other)
    assert shared.shared_curve_used(shared.fit(basis, dipped, rig.fans.enabled))


def test_a_shared_curve_sd_outside_its_range_is_refused():
    with pytest.raises(ConfigError, match='shared_curve_sd'):
        AdaptiveUpdate(shared_curve_sd=-0.1)


def test_the_rule_bends_a_shared_curve_only_where_the_commissioning_shows_one(rig, prior, rng):
    """The commissioning's maps run every fan across its range: the rule bends the curve the
    fans share where they show a dip, and not where only the run's own map is off the prior."""
    kp = rig.key_points
    basis = FanBasis.from_term(prior, kp)
    dipped, field = _dip_maps(rig, basis, rng, rng.uniform(0.25, 0.45, 7))
    plain, _ = _dip_maps(rig, basis, rng, np.zeros(7))
    U = np.full(7, 0.3)
    target = prior(np.full(7, 0.35), kp)
    rule = AdaptiveUpdate(curve_sd=0.07, shared_curve_sd=0.1)

    def bent(maps, measured):
        commissioning = [PastIteration(V, F, None, {}) for V, F, _ in maps]
        return rule.step(_inputs(rig, prior, U, measured, target, prior_maps=commissioning)).info['shared_curve']

    assert bent(dipped, field(U))
    assert not bent(plain, field(U))
    assert not AdaptiveUpdate(curve_sd=0.07).step(_inputs(rig, prior, U, field(U), target, prior_maps=[
        PastIteration(V, F, None, {}) for V, F, _ in dipped])).info['shared_curve']


def test_a_fit_to_the_commissioning_maps_is_remembered_only_for_the_same_maps(rig, prior, rng):
    """Every step of a run refits the commissioning's maps alone (the shared curve's test, the
    anchor); the remembered fit is the fit itself, and another map, setting or fan set is not
    served the old one."""
    from dataclasses import replace
    from wind_shaper.control.adaptive import _commissioning_fit
    basis = FanBasis.from_term(prior, rig.key_points)
    maps, _ = _dip_maps(rig, basis, rng, rng.uniform(0.25, 0.45, 7))
    on = np.asarray(rig.fans.enabled, bool)
    fit = ShapeFit(noise_std=0.05, curve_sd=0.07, shared_curve_sd=0.1)
    first = _commissioning_fit(fit, basis, maps, on)
    np.testing.assert_array_equal(first, fit.fit(basis, maps, on))
    np.testing.assert_array_equal(_commissioning_fit(fit, basis, maps, on), first)
    moved = [(U, F + (0.05 if i == 3 else 0.0), w) for i, (U, F, w) in enumerate(maps)]
    np.testing.assert_array_equal(_commissioning_fit(fit, basis, moved, on), fit.fit(basis, moved, on))
    assert not np.array_equal(_commissioning_fit(fit, basis, moved, on), first)
    own = replace(fit, shared_curve_sd=0.0)
    np.testing.assert_array_equal(_commissioning_fit(own, basis, maps, on), own.fit(basis, maps, on))
    off = on.copy()
    off[2] = False
    np.testing.assert_array_equal(_commissioning_fit(fit, basis, maps, off), fit.fit(basis, maps, off))
