"""JetInteractionPower, the jet-interaction family's wider form: its analytic Jacobian, its
reduction to JetInteraction at exponent 1/2, the thrust law its exponent sets, the model-file
round trip and its bounds."""
import numpy as np
import pytest

from wind_shaper.core.errors import ConfigError
from wind_shaper.core.geometry import FanArray
from wind_shaper.model import (TERMS, CentralRing, FanJets, JetInteraction, JetInteractionPower,
                               fan_thrust, finite_difference_jacobian, term_from_dict)


@pytest.fixture
def base(rig):
    jets = FanJets(rig.fans, thrust_higher=(0.1, 2.5, 11.0), thrust_lower=(0.05, 2.0, 8.0), sigma=0.14)
    return jets + CentralRing(rig.fans, thrust=(0.0, 3.0, 7.0), offset=0.2, sigma=0.25)


def test_registered_and_exported():
    assert TERMS['jet_interaction_power'] is JetInteractionPower
    assert issubclass(JetInteractionPower, JetInteraction)


@pytest.mark.parametrize('exponent', [0.25, 0.5, 0.8, 1.3, 2.0])
def test_jacobian_matches_central_differences(rig, base, rng, exponent):
    term = JetInteractionPower(rig.fans, base, strength=0.4, width=1.2, exponent=exponent)
    pts = rig.key_points[::2]
    for _ in range(3):
        U = rng.uniform(0.05, 0.85, rig.fans.n_fans)
        J = term.jacobian(U, pts)
        assert J.shape == (len(pts), rig.fans.n_fans)
        np.testing.assert_allclose(J, finite_difference_jacobian(term, U, pts), rtol=1e-5, atol=2e-6)
    # one command row per point (the batched form the fits use)
    Ub = rng.uniform(0.05, 0.85, (len(pts), rig.fans.n_fans))
    step = 1e-6
    for j in (0, 6):
        dU = np.zeros_like(Ub)
        dU[:, j] = step
        fd = (term(Ub + dU, pts) - term(Ub - dU, pts)) / (2 * step)
        np.testing.assert_allclose(term.jacobian(Ub, pts)[:, j], fd, rtol=1e-5, atol=2e-6)


def test_exponent_one_half_is_jet_interaction(rig, base, rng):
    U = rng.uniform(0.0, 0.9, (30, rig.fans.n_fans))
    Z = rng.uniform(-0.34, 0.34, (30, 2))
    old = JetInteraction(rig.fans, base, strength=0.35, width=0.8)
    for ref in (1.0, 4.0, 9.0):  # the reference thrust only rescales strength away from 1/2
        new = JetInteractionPower(rig.fans, base, strength=0.35, width=0.8, exponent=0.5, thrust_ref=ref)
        np.testing.assert_allclose(new(U, Z), old(U, Z), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(new.jacobian(U, Z), old.jacobian(U, Z), rtol=1e-10, atol=1e-12)
    other = JetInteractionPower(rig.fans, base, strength=0.35, width=0.8, exponent=0.9)
    assert not np.allclose(other(U, Z), old(U, Z))


def test_exponent_sets_how_the_gap_force_grows_with_thrust():
    # two alike fans, one pair: the gap force is strength T_ref ((T^2 + eps) / T_ref^2)^p B(z),
    # against strength sqrt(T^2 + eps) B(z) for JetInteraction with the same bridge B
    fans = FanArray.grid(1, 2, 0.25)
    base = FanJets(fans, thrust_higher=(0.0, 2.0, 9.0), thrust_lower=(0.0, 2.0, 9.0), sigma=0.14)
    mid = [[0.0, 0.0]]
    ref, p, eps = 4.0, 1.2, 1e-4
    term = JetInteractionPower(fans, base, strength=0.3, exponent=p, thrust_ref=ref)
    plain = JetInteraction(fans, base, strength=0.3)
    assert len(term.pairs) == 1
    for u in (0.2, 0.5, 0.9):
        U = np.full(2, u)
        T = fan_thrust(base, U[None])[0][0]
        assert T[0] == pytest.approx(T[1])
        x = T[0] * T[1] + eps
        extra = (term(U, mid) - base(U, mid))[0]
        plain_extra = (plain(U, mid) - base(U, mid))[0]
        assert plain_extra > 0
        assert extra / plain_extra == pytest.approx(ref * (x / ref ** 2) ** p / np.sqrt(x), rel=1e-9)
    # strength 0 is no effect whatever the exponent
    none = JetInteractionPower(fans, base, strength=0.0, exponent=1.7)
    U = np.full(2, 0.6)
    pts = np.random.default_rng(3).uniform(-0.3, 0.3, (20, 2))
    np.testing.assert_allclose(none(U, pts), base(U, pts), atol=1e-12)


def test_round_trip_through_the_model_file_form(rig, base, rng):
    term = JetInteractionPower(rig.fans, base, strength=0.45, width=1.4, exponent=1.15,
                               reach=1.5, thrust_ref=3.0, fixed=('width',))
    spec = term.to_dict()
    assert spec['kind'] == 'jet_interaction_power' and spec['exponent'] == pytest.approx(1.15)
    assert spec['thrust_ref'] == 3.0 and spec['reach'] == 1.5 and spec['fixed'] == ['width']
    rebuilt = term_from_dict(spec, rig.fans)
    assert type(rebuilt) is JetInteractionPower and repr(rebuilt) == repr(term)
    assert rebuilt.theta_names == term.theta_names and rebuilt.fixed_names == ('width',)
    assert term.theta_names[-2:] == ['jet_interaction_power.strength', 'jet_interaction_power.exponent']
    U = rng.uniform(0.05, 0.8, rig.fans.n_fans)
    np.testing.assert_allclose(rebuilt(U, rig.key_points), term(U, rig.key_points))
    # the fitted parameters move through theta; structure survives a clone
    moved = term.with_theta(np.concatenate([term.theta[:-2], [0.3, 0.7]]))
    assert (moved.strength, moved.exponent, moved.thrust_ref, moved.reach) == (0.3, 0.7, 3.0, 1.5)
    assert not np.allclose(moved(U, rig.key_points), term(U, rig.key_points))


@pytest.mark.parametrize('params, words', [
    ({'exponent': 0.1},
     r'JetInteractionPower\.exponent = \[0\.1\] is outside its bounds \[\[0\.25, 2\.0\]\]'),
    ({'exponent': 2.5}, r'JetInteractionPower\.exponent = \[2\.5\] is outside its bounds'),
    ({'exponent': float('nan')}, r'JetInteractionPower\.exponent'),
    ({'strength': -0.1},
     r'JetInteractionPower\.strength = \[-0\.1\] is outside its bounds \[\[0\.0, 2\.0\]\]'),
    ({'width': 5.0}, r'JetInteractionPower\.width'),
    ({'thrust_ref': 0.0}, r'thrust_ref must be a positive thrust \[N\]; got 0\.0'),
    ({'reach': 4.0}, r'reach must be in \[1, 3\] hub spacings'),
])
def test_bounds_are_refused_with_a_clear_error(rig, base, params, words):
    with pytest.raises(ConfigError, match=words):
        JetInteractionPower(rig.fans, base, **{"strength": 0.2, **params})
    term = JetInteractionPower(rig.fans, base, strength=0.2)
    lo, hi = term.bounds[-1]
    assert (lo, hi) == (0.25, 2.0) and term.theta_names[-1].endswith('exponent')
