"""The discrepancy model: a term with no physics that describes, and can stand in for, what the
candidate library does not explain (wind_shaper.model.discrepancy, workbench.discrepancy)."""
import numpy as np
import pytest

from wind_shaper.core.errors import ConfigError
from wind_shaper.model import (CommandScale, Discrepancy, FieldFormula, Product, command_features,
                               finite_difference_jacobian, load_model, save_model, term_from_dict)
from wind_shaper.sim import make_effect
from wind_shaper.workbench.commands import add_command, simulated_sweeps
from wind_shaper.workbench.diagnose import Diagnosis
from wind_shaper.workbench.data import FitData
from wind_shaper.workbench.discrepancy import describe_map, disc_grid, fit_discrepancy


def _term(fans, rng):
    centres = disc_grid(0.36, 0.1)
    features = ['one', 'thrust', 'balance', f'fan:{fans.names[1]}']
    return Discrepancy(fans, centres, 0.08, features, rng.normal(0, 0.2, (len(centres), len(features))))


def test_discrepancy_jacobian_matches_finite_differences(wb_setup, rng):
    fans = wb_setup.geometry.fans
    term = _term(fans, rng)
    Z = rng.uniform(-0.3, 0.3, (40, 2))
    U = rng.uniform(0.1, 0.9, fans.n_fans)
    np.testing.assert_allclose(term.jacobian(U, Z), finite_difference_jacobian(term, U, Z), atol=1e-6)
    formula = FieldFormula(fans, ['x', f'bump:{fans.names[0]}'], ['thrust', f'fan:{fans.names[0]}'],
                           [[0.2, 0.0], [0.0, -0.5]])
    np.testing.assert_allclose(formula.jacobian(U, Z), finite_difference_jacobian(formula, U, Z), atol=1e-6)
    assert 'x T' in formula.formula() and f'bump over {fans.names[0]}' in formula.formula()


def test_discrepancy_round_trips_through_a_model_file(wb_setup, reference, rng, tmp_path):
    fans = wb_setup.geometry.fans
    model = reference + _term(fans, rng)
    save_model(tmp_path / 'm.yaml', model)
    back = load_model(tmp_path / 'm.yaml', fans)
    Z = rng.uniform(-0.3, 0.3, (25, 2))
    U = rng.uniform(0.0, 0.9, fans.n_fans)
    np.testing.assert_allclose(back(U, Z), model(U, Z), atol=1e-9)
    assert len(back.theta) == len(reference.theta)  # nothing of it is moved by a refit


def test_a_command_scale_is_the_same_everywhere_and_round_trips(wb_setup, reference, rng, tmp_path):
    fans = wb_setup.geometry.fans
    scale = CommandScale(fans, ['one', 'thrust'], [[0.05, -0.3]])
    Z = rng.uniform(-0.3, 0.3, (30, 2))
    U = rng.uniform(0.1, 0.9, fans.n_fans)
    thrust = float(np.mean(U ** 2))
    np.testing.assert_allclose(scale(U, Z), 0.05 - 0.3 * thrust)
    np.testing.assert_allclose(scale.jacobian(U, Z), finite_difference_jacobian(scale, U, Z), atol=1e-6)
    model = reference + Product(reference, scale)  # the model's own field, 5 % - 30 % x thrust more
    save_model(tmp_path / 's.yaml', model)
    np.testing.assert_allclose(load_model(tmp_path / 's.yaml', fans)(U, Z), model(U, Z), atol=1e-9)
    with pytest.raises(ConfigError, match='needs 1 x 2 weights'):
        CommandScale(fans, ['one', 'thrust'], [1.0, 2.0, 3.0])


def _cells(fans, rng, n_sweeps=10, per_sweep=150):
    U = np.repeat(rng.uniform(0.0, 0.9, (n_sweeps, fans.n_fans)), per_sweep, axis=0)
    Z = rng.uniform(-0.3, 0.3, (len(U), 2))
    sweep = np.repeat(np.arange(n_sweeps), per_sweep)
    return U, Z, sweep


def test_the_discrepancy_takes_the_models_own_scale_only_where_it_predicts_better(
        wb_setup, reference, rng):
    """A shared supply that sags as the total flow grows scales the model's own field, which
    bumps cannot follow across varied commands: fitted with the scale, the discrepancy finds it
    (close to the true weights) and predicts left-out sweeps better; on a residual with no such
    scale, the scale is left out."""
    fans = wb_setup.geometry.fans
    U, Z, sweep = _cells(fans, rng)
    field = reference(U, Z)
    thrust = command_features(fans, ['thrust'], U)[0][:, 0]
    noise = rng.normal(0, 0.05, len(U))
    sagging = FitData(U, Z, field * (1.0 + 0.04 - 0.25 * thrust) + noise, sweep, np.ones(len(U), int))
    plain = fit_discrepancy(reference, sagging, wb_setup.geometry)
    scaled = fit_discrepancy(reference, sagging, wb_setup.geometry, scale_features=('one', 'thrust'))
    assert plain.scale is None and scaled.scale is not None
    np.testing.assert_allclose(scaled.scale.weights[0], [0.04, -0.25], atol=0.03)
    added = scaled.added_to(reference)  # the model x (1 + s(U)) + the bumps: what the data show
    np.testing.assert_allclose(added(U, Z), field + scaled.value(U, Z), atol=1e-9)
    assert np.sqrt(np.mean((added(U, Z) - sagging.y) ** 2)) < 0.06
    assert scaled.cv_rmse < 0.7 * plain.cv_rmse, (scaled.cv_rmse, plain.cv_rmse)
    bump = np.exp(-np.sum((Z - [0.1, -0.1]) ** 2, 1) / (2 * 0.06 ** 2))
    patch = FitData(U, Z, field + 0.5 * bump + noise, sweep, np.ones(len(U), int))
    assert fit_discrepancy(reference, patch, wb_setup.geometry, scale_features=('one', 'thrust')).scale is None


def test_discrepancy_refuses_bad_input_with_what_to_do(wb_setup):
    fans = wb_setup.geometry.fans
    with pytest.raises(ConfigError, match='unknown command feature .fan:XX.*fan:NAME'):
        Discrepancy(fans, [[0, 0]], 0.05, ['fan:XX'], [[1.0]])
    with pytest.raises(ConfigError, match='needs 1 x 2 weights'):
        Discrepancy(fans, [[0, 0]], 0.05, ['one', 'thrust'], [1.0])
    with pytest.raises(ConfigError, match='width must be > 0'):
        Discrepancy(fans, [[0, 0]], 0.0, ['one'], [1.0])
    with pytest.raises(Exception, match='unknown spatial mode'):
        term_from_dict({'kind': 'field_formula', 'modes': ['spiral'], 'features': ['one'],
                        'weights': [1.0]}, fans)


def test_maps_are_put_in_words(wb_setup):
    geo = wb_setup.geometry
    grid = disc_grid(geo.sweep_radius, 0.02)
    x, y = grid.T
    assert describe_map(np.full(len(grid), -0.3), grid, geo).startswith('about uniform')
    tilt = describe_map(0.5 * (np.cos(np.radians(120)) * x + np.sin(np.radians(120)) * y), grid, geo)
    assert tilt.startswith('a tilt') and 'towards 120 deg' in tilt
    ring = describe_map(np.exp(-(np.hypot(x, y) - 0.18) ** 2 / (2 * 0.03 ** 2)), grid, geo)
    assert ring.startswith('radial') and 'ring at r = 0.1' in ring
    hub = geo.fans.positions[geo.fans.names.index('HM2')]
    patch = describe_map(-0.4 * np.exp(-np.sum((grid - hub) ** 2, axis=1) / (2 * 0.04 ** 2)), grid, geo)
    assert patch.startswith('local') and 'over fan HM2' in patch and 'model is high' in patch


# -- on the simulated tunnel with physics the library lacks (DATA_SEED, 12 sweeps) ----------------

def _words(d):
    assert d.discrepancy_ is not None, d.summary()
    return ' '.join(d.discrepancy_.words)


@pytest.mark.slow
def test_a_blocked_patch_is_described_as_a_fraction_of_the_force_where_it_is(diagnosed):
    d, (effect,) = diagnosed('honeycomb_blockage')
    assert d.steps_ == []
    text = _words(d)
    assert 'fixed fraction of the local force' in text and 'model is high there' in text
    fit = d.discrepancy_
    assert fit.readings['fraction']['r2'] >= 0.6
    centre = [float(v) for v in text.split('centred at (')[1].split(')')[0].split(',')]
    assert np.hypot(centre[0] - effect.x, centre[1] - effect.y) < 0.04, text
    assert fit.offered and fit.heldout_after <= 0.8 * fit.heldout_before
    assert 'model add --effect discrepancy' in d.summary()


@pytest.mark.slow
def test_a_room_draft_is_described_as_a_displaced_field(diagnosed):
    d, (effect,) = diagnosed('side_draft')
    text = _words(d)
    assert 'whole field displaced' in text, text
    dx, dy = d.discrepancy_.readings['displacement']['shift_m']
    angle = np.degrees(np.arctan2(dy, dx) - np.arctan2(effect.dy, effect.dx))
    assert abs((angle + 180) % 360 - 180) < 25, (dx, dy)


@pytest.mark.slow
def test_a_starved_inlet_is_described_as_the_models_field_falling_with_the_total_thrust(
        diagnosed, wb_setup, reference):
    # every fan runs at U / (1 + 0.6 mean U): the model's own field, less as the total grows
    d, _ = diagnosed('plenum_starvation')
    q = d.discrepancy_
    assert q.scale is not None
    weights = dict(zip(q.scale.features, q.scale.weights[0]))
    assert weights['thrust'] < -0.2, weights
    assert max(q.shares, key=q.shares.get) in ('thrust', 'scale')
    assert 'grows with the total thrust of all fans' in _words(d) and 'the model is high' in _words(d)
    # where the scale carries most of it (seed 100), it is said in those words, and offered
    data = simulated_sweeps(wb_setup.make_sim(seed=100, effects=[make_effect('plenum_starvation')]), 12,
                            seed=100)
    q = Diagnosis().fit(reference, data, wb_setup.geometry).discrepancy_
    assert 'of it is the model\'s own field scaled' in ' '.join(q.words), q.words
    assert 'every fan gives less as the total flow grows: a starved inlet' in ' '.join(q.words)
    assert q.offered and q.heldout_after < 0.5 * q.heldout_before
    assert q.to_json()['scale']['kind'] == 'command_scale'


@pytest.mark.slow
def test_nothing_is_described_when_the_model_explains_the_data(diagnosed):
    assert diagnosed()[0].discrepancy_ is None
    d, _ = diagnosed('weak_fan')
    assert d.steps_ and d.discrepancy_ is None, d.summary()


@pytest.mark.slow
def test_adding_the_discrepancy_lowers_the_heldout_error_and_saves_a_loadable_model(
        wb_setup, reference, sim_data, tmp_path):
    data, _ = sim_data('stand_wake')
    out = add_command(reference, ['discrepancy'], data, wb_setup.geometry, tmp_path / 'add',
                      save=tmp_path / 'model.yaml')
    assert out.after['model_rmse'] <= 0.7 * out.before['model_rmse'], out.change
    assert [a['effect'] for a in out.added] == ['discrepancy']
    report = (tmp_path / 'add' / 'report.md').read_text()
    assert 'names no physics' in report and 'fixed fraction of the local force' in report
    back = load_model(tmp_path / 'model.yaml', wb_setup.geometry.fans)
    U, Z = data.commands[3], data.sweeps[3].positions[:50]
    np.testing.assert_allclose(back(U, Z), out.model(U, Z), atol=1e-9)


@pytest.mark.slow
def test_an_effect_of_simple_form_is_written_out_as_a_formula(diagnosed):
    # a warm wall: a fixed tilt, no family stands for it; the formula is that tilt
    d, (effect,) = diagnosed('thermal_gradient')
    assert d.steps_ == [] and d.formula_ is not None and d.formula_.offered, d.summary()
    term = d.formula_.term
    assert set(term.mode_names) == {'x', 'y'} and term.features == ('one',)
    e = np.radians(effect.direction)
    truth = effect.slope * term.radius / 0.1 * np.array([np.cos(e), np.sin(e)])
    got = term.weights[[term.mode_names.index('x'), term.mode_names.index('y')], 0]
    np.testing.assert_allclose(got, truth, rtol=0.25)
    assert 'A short formula fits it' in d.summary() and 'x / R' in d.summary()


@pytest.mark.slow
@pytest.mark.parametrize('effect', ['honeycomb_blockage', 'stand_wake', 'side_draft', 'plenum_starvation'])
def test_no_formula_is_offered_for_physics_of_no_simple_form(effect, diagnosed):
    d, _ = diagnosed(effect)
    assert d.formula_ is None or not d.formula_.offered, d.formula_.term.formula()


@pytest.mark.slow
def test_the_diagnosis_report_shows_what_lies_outside(wb_setup, reference, sim_data, tmp_path):
    from wind_shaper.workbench.commands import diagnose_command
    data, _ = sim_data('honeycomb_blockage')
    d = diagnose_command(reference, data, wb_setup.geometry, tmp_path / 'diag')
    report = (tmp_path / 'diag' / 'report.md').read_text()
    assert (tmp_path / 'diag' / 'discrepancy.png').stat().st_size > 10000
    assert '## What lies outside the library' in report and d.discrepancy_.words[1] in report
    summary = __import__('json').loads((tmp_path / 'diag' / 'summary.json').read_text())
    assert summary['discrepancy']['offered'] and summary['discrepancy']['readings']['fraction']['r2'] >= 0.6
