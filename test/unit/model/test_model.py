"""Model terms: values, analytic Jacobians, parameters, composition, persistence."""
import numpy as np
import pytest

from wind_shaper.core.errors import ConfigError, ModelFileError
from wind_shaper.core.geometry import FanArray
from wind_shaper.model import (CentralRing, FanJets, Product, Sum, TERMS, Term,
                               finite_difference_jacobian, paper_prior, term_from_dict)


def _instances(fans):
    jets = FanJets(fans, thrust_higher=(0.1, 2.5, 11.0), thrust_lower=(0.05, 2.0, 8.0), sigma=0.14)
    ring = CentralRing(fans, thrust=(0.0, 3.0, 7.0), offset=0.2, sigma=0.25)
    return {'jets': jets, 'ring': ring, 'sum': jets + ring, 'product': jets * ring,
            'nested': (jets + ring) * ring}


@pytest.mark.parametrize('name', ['jets', 'ring', 'sum', 'product', 'nested'])
def test_every_term_jacobian_matches_finite_differences(rig, rng, name):
    term = _instances(rig.fans)[name]
    for _ in range(3):
        U = rng.uniform(0.05, 0.8, rig.fans.n_fans)
        J = term.jacobian(U, rig.key_points)
        J_fd = finite_difference_jacobian(term, U, rig.key_points)
        assert J.shape == (len(rig.key_points), rig.fans.n_fans)
        np.testing.assert_allclose(J, J_fd, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize('name', ['jets', 'ring', 'sum', 'product', 'nested'])
def test_every_term_round_trips_theta_and_dict(rig, rng, name):
    term = _instances(rig.fans)[name]
    U = rng.uniform(0, 0.7, rig.fans.n_fans)
    # with_theta(theta) is the same model
    same = term.with_theta(term.theta)
    np.testing.assert_allclose(same(U, rig.key_points), term(U, rig.key_points))
    # and a changed theta changes it and is reflected in theta
    bumped = term.with_theta(term.theta * 1.05)
    np.testing.assert_allclose(bumped.theta, term.theta * 1.05)
    assert not np.allclose(bumped(U, rig.key_points), term(U, rig.key_points))
    # persistence
    rebuilt = term_from_dict(term.to_dict(), rig.fans)
    np.testing.assert_allclose(rebuilt(U, rig.key_points), term(U, rig.key_points))
    assert len(term.theta_names) == len(term.theta) == len(term.bounds)


def test_fan_jets_is_the_papers_formula(rig):
    jets = FanJets(rig.fans, thrust_higher=(0.0, 1.0, 10.0), thrust_lower=(0.0, 2.0, 5.0), sigma=0.15)
    U = np.array([0.3, 0.4, 0.5, 0.6, 0.2, 0.1, 0.7])
    z = np.array([[0.05, -0.1]])
    expected = 0.0
    for j, fan in enumerate(rig.fans.fans):
        if fan.group == 'central':
            continue  # the central fan is the ring term's
        c = (0.0, 1.0, 10.0) if fan.group == 'higher' else (0.0, 2.0, 5.0)
        P = c[0] + c[1] * U[j] + c[2] * U[j] ** 2
        d2 = (z[0, 0] - fan.x) ** 2 + (z[0, 1] - fan.y) ** 2
        expected += P * np.exp(-d2 / 0.15 ** 2)
    assert jets(U, z)[0] == pytest.approx(expected, rel=1e-12)


def test_central_ring_is_low_on_axis_high_on_ring(rig):
    ring = CentralRing(rig.fans, thrust=(0, 2, 9), offset=0.02, sigma=0.35, ring_scale=1.0)
    U = np.zeros(7)
    U[6] = 0.5
    on_axis = ring(U, [[0.0, 0.0]])[0]
    on_ring = ring(U, [[0.25, 0.0]])[0]
    assert on_ring > on_axis > 0
    # the paper's formula exactly (ring_scale 1 m)
    P = 2 * 0.5 + 9 * 0.25
    assert on_ring == pytest.approx(P * (0.02 + 0.0625) * np.exp(-0.0625 / 0.35 ** 2))


def test_batched_commands_pair_with_points(rig, rng):
    term = paper_prior(rig.fans)
    U = rng.uniform(0, 0.7, (5, 7))
    Z = rng.uniform(-0.3, 0.3, (5, 2))
    batched = term(U, Z)
    one_by_one = [term(U[i], Z[i:i + 1])[0] for i in range(5)]
    np.testing.assert_allclose(batched, one_by_one)


def test_bounds_and_fixed_parameters(rig):
    with pytest.raises(ConfigError, match='sigma'):
        FanJets(rig.fans, sigma=-0.1)
    ring = CentralRing(rig.fans)
    assert 'ring_scale' not in ring.theta_names  # fixed by default, as in the paper
    jets = FanJets(rig.fans, fixed=('sigma',))
    assert 'sigma' not in jets.theta_names and len(jets.theta) == 6
    with pytest.raises(ConfigError, match='no parameters'):
        FanJets(rig.fans, fixed=('nonsense',))


def test_composition_operators_and_repr(rig):
    jets, ring = FanJets(rig.fans), CentralRing(rig.fans)
    assert isinstance(jets + ring, Sum) and isinstance(jets * ring, Product)
    text = repr((jets + ring) * ring)
    assert text.startswith('(FanJets(') and '+ CentralRing(' in text and ') * CentralRing(' in text


@pytest.mark.fault
def test_model_file_errors_name_the_problem(rig, fault_row):
    with pytest.raises(ModelFileError, match='unknown model term kind'):
        term_from_dict({'kind': 'warp_drive'}, rig.fans)
    with pytest.raises(ModelFileError, match='kind'):
        term_from_dict(['not', 'a', 'mapping'], rig.fans)
    with pytest.raises(ModelFileError, match='fan_jets'):
        term_from_dict({'kind': 'fan_jets', 'sigma': 'wide'}, rig.fans)
    fault_row('a corrupted or wrong model file',
              'refused with the problem named; the model in use stays', True)


def test_registry_holds_every_term_kind():
    assert {'fan_jets', 'central_ring'} <= set(TERMS)
    assert all(issubclass(cls, Term) for cls in TERMS.values())


def test_works_for_any_number_of_fans():
    fans = FanArray.grid(4, 5, 0.1)
    term = FanJets(fans)
    pts = np.random.default_rng(0).uniform(-0.3, 0.3, (50, 2))
    U = np.full(20, 0.4)
    np.testing.assert_allclose(term.jacobian(U, pts), finite_difference_jacobian(term, U, pts),
                               rtol=1e-5, atol=1e-7)


def test_a_parameter_is_named_for_people_by_its_term(rig):
    """Printed parameters name the term they belong to, however deep the composition."""
    term = paper_prior(rig.fans)
    shown = [term.display_name(n) for n in term.theta_names]
    assert 'FanJets.thrust_higher[1]' in shown and 'CentralRing.offset' in shown
    assert not any('__' in s for s in shown)
    nested = Sum(term, FanJets(rig.fans))
    assert nested.display_name('k1__k2__sigma') == 'CentralRing.sigma'
    assert nested.display_name('k2__sigma') == 'FanJets.sigma'
