"""FieldShift: the whole field displaced, and the sweep calibration that fits it by default."""
import numpy as np
import pytest

from wind_shaper.control.basis import FanBasis, _fan_polynomials
from wind_shaper.model import (TERMS, FanJets, CentralRing, FieldShift, fan_landing, fan_part,
                               finite_difference_jacobian, paper_prior, sweep_prior, term_from_dict)


def _prior(fans):
    jets = FanJets(fans, thrust_higher=(0.1, 2.5, 11.0), thrust_lower=(0.05, 2.0, 8.0), sigma=0.14)
    return jets + CentralRing(fans, thrust=(0.0, 3.0, 7.0), offset=0.2, sigma=0.25)


def test_the_shifted_field_is_the_field_read_where_it_came_from(rig, rng):
    inner = _prior(rig.fans)
    moved = FieldShift(rig.fans, inner, dx=0.06, dy=-0.03)
    U = rng.uniform(0.1, 0.7, rig.fans.n_fans)
    Z = rig.key_points
    np.testing.assert_allclose(moved(U, Z), inner(U, Z - [0.06, -0.03]))
    # each fan's part moves with it, and the parts still sum to the field
    parts = sum(fan_part(moved, U, Z, j)[0] for j in range(rig.fans.n_fans))
    np.testing.assert_allclose(parts, moved(U, Z), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fan_landing(moved, 2), rig.fans.positions[2] + [0.06, -0.03])
    # and a shift of zero is no shift
    np.testing.assert_allclose(FieldShift(rig.fans, inner)(U, Z), inner(U, Z))


def test_its_jacobians_match_finite_differences(rig, rng):
    moved = FieldShift(rig.fans, _prior(rig.fans), dx=-0.05, dy=0.04)
    U = rng.uniform(0.1, 0.7, rig.fans.n_fans)
    J = moved.jacobian(U, rig.key_points)
    np.testing.assert_allclose(J, finite_difference_jacobian(moved, U, rig.key_points), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(moved.sparse_jacobian(U, rig.key_points, 1e-12).toarray(), J, atol=1e-8)


def test_it_round_trips_through_a_model_file_and_its_parameters(rig, rng, tmp_path):
    from wind_shaper.model import load_model, save_model
    moved = FieldShift(rig.fans, _prior(rig.fans), dx=0.02, dy=0.01)
    assert TERMS['field_shift'] is FieldShift
    U = rng.uniform(0.1, 0.7, rig.fans.n_fans)
    for again in (term_from_dict(moved.to_dict(), rig.fans),
                  load_model(save_model(tmp_path / 'prior.yaml', moved), rig.fans)):
        np.testing.assert_allclose(again(U, rig.key_points), moved(U, rig.key_points))
    assert moved.theta_names[-2:] == ['field_shift.dx', 'field_shift.dy']
    bumped = moved.with_theta(np.concatenate([moved.theta[:-2], [0.05, -0.02]]))
    assert (bumped.dx, bumped.dy) == (0.05, -0.02)


def test_the_update_rules_factorisation_reads_it_as_the_prior_read_elsewhere(rig):
    """The adaptive update factorises the prior fan by fan: a shifted prior is the unshifted one
    read at the key points moved back, and keeps the paper prior's fast thrust curves."""
    inner = _prior(rig.fans)
    d = np.array([0.07, 0.02])
    a = FanBasis.from_term(FieldShift(rig.fans, inner, dx=d[0], dy=d[1]), rig.key_points)
    b = FanBasis.from_term(inner, rig.key_points - d)
    for name in ('shape', 'dx', 'dy', 'offset'):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-9)
    np.testing.assert_allclose(_fan_polynomials(FieldShift(rig.fans, inner)), _fan_polynomials(inner))


def test_the_sweep_prior_is_the_papers_with_the_shift_free(rig):
    term = sweep_prior(rig.fans)
    assert isinstance(term, FieldShift) and (term.dx, term.dy) == (0.0, 0.0)
    assert term.theta_names[:-2] == paper_prior(rig.fans).theta_names


@pytest.mark.parametrize('shift', [(0.06, -0.03), (0.0, 0.0)])
def test_commissioning_keeps_the_shift_where_the_field_is_displaced_and_only_there(shift):
    """A steady draft displaces every jet alike (the simulator's side draft, its reference so
    large that the displacement hardly changes with the thrust): from six designed sweeps and the
    level sweeps the default calibration keeps the field's landing point, within a centimetre of
    the draft's, because it predicts the held-out sweeps better; on the tunnel without one it
    keeps the paper's prior, which predicts them as well or better."""
    from wind_shaper.app import Setup
    from wind_shaper.sim import effects_from_config
    from wind_shaper.workbench.calibrate import SHIFT_GAIN, commission_from_design
    setup = Setup.load()
    effects = [{'name': 'side_draft', 'dx': shift[0], 'dy': shift[1], 'reference': 1e3}] if any(shift) else []
    sim = setup.make_sim(seed=0, effects=list(effects_from_config(effects)))
    cal = commission_from_design(sim, 'lhs:6+level', setup.shaping.u_min, setup.shaping.u_max,
                                 n_samples=setup.shaping.samples_per_sweep, seed=0)
    (kept, kept_rmse), (other, other_rmse) = cal.compared
    assert cal.heldout_rmse == kept_rmse
    if any(shift):
        assert isinstance(cal.model, FieldShift) and 'shifted' in kept
        assert kept_rmse <= (1 - SHIFT_GAIN) * other_rmse
        assert np.hypot(cal.model.dx - shift[0], cal.model.dy - shift[1]) < 0.01
    else:
        assert not isinstance(cal.model, FieldShift) and 'shifted' in other


def test_the_workbench_puts_a_fans_finding_inside_the_shift(rig, rng):
    """A model calibrated with the shift is extended by the workbench like any other: a per-fan
    term goes around the fans' core, inside the shift, so the finding moves with the field."""
    from wind_shaper.model import FanGain, walk
    from wind_shaper.workbench.library import apply_candidate, default_library
    moved = FieldShift(rig.fans, _prior(rig.fans), dx=0.04, dy=-0.02)
    cands = {c.name: c for c in default_library().candidates(moved, rig)}
    extended = apply_candidate(moved, cands['fan_gain[HM2]'], gain=0.8)
    assert isinstance(extended, FieldShift) and (extended.dx, extended.dy) == (0.04, -0.02)
    assert any(isinstance(t, FanGain) for t in walk(extended.inner))
    U = rng.uniform(0.1, 0.7, rig.fans.n_fans)
    expected = FanGain(rig.fans, _prior(rig.fans), fan='HM2', gain=0.8)(U, rig.key_points - [0.04, -0.02])
    np.testing.assert_allclose(extended(U, rig.key_points), expected)
