"""Jet interaction in another form (wind_shaper.sim.unmodelled_effects.MergingJets: a gap force
growing as (T_i T_j)^0.75 over an elongated bridge): the jet-interaction family's wider
candidate (free thrust exponent) finds it, where the one-form candidate alone is refused by the
check across sweeps. The simulated effect itself is checked against its docstring's law."""
import numpy as np
import pytest

from wind_shaper.sim import Imperfections, NoiseModel, SimulatedTunnel
from wind_shaper.sim.unmodelled_effects import OTHER_FORM, MergingJets
from wind_shaper.workbench.diagnose import Diagnosis
from wind_shaper.workbench.library import (FAMILIES, Library, _interaction_family, apply_candidate,
                                           candidate_for_hidden_effect, default_library)


def _family(reference, geometry):
    return {c.name: c.family for c in default_library().candidates(reference, geometry)}


def test_the_simulated_bridge_follows_its_law(wb_setup):
    rig = wb_setup.geometry
    perfect = SimulatedTunnel(rig, imperfections=Imperfections.none(rig.fans.n_fans),
                              noise=NoiseModel.zero())
    effect = MergingJets()
    assert MergingJets in OTHER_FORM
    sim = perfect.with_effects([effect])
    a, b = rig.fans.positions[0], rig.fans.positions[1]  # LM1 and HM1, neighbours on the ring
    mid = 0.5 * (a + b)
    along = (b - a) / np.linalg.norm(b - a)
    across = np.array([-along[1], along[0]])
    half = 0.5 * np.linalg.norm(b - a)
    for u in (0.3, 0.6, 0.9):
        pwm = np.zeros(7)
        pwm[[0, 1]] = u  # only these two run: every other pair has a fan at zero thrust
        t = perfect.thrust(pwm)
        peak = effect.strength * effect.thrust_ref * (t[0] * t[1] / effect.thrust_ref ** 2) ** effect.exponent
        pts = np.array([mid, mid + 0.5 * half * along, mid + 0.05 * across])
        extra = sim.point_field(pwm, pts) - perfect.point_field(pwm, pts)
        assert extra[0] == pytest.approx(peak, rel=1e-9)
        assert extra[1] == pytest.approx(peak * np.exp(-0.25), rel=1e-9)  # along: length x half
        assert extra[2] == pytest.approx(peak * np.exp(-(0.05 / effect.width) ** 2), rel=1e-9)
    # faster than sqrt(T_i T_j): weak at low thrust, strong at high (against JetInteraction)
    low, high = np.zeros(7), np.zeros(7)
    low[[0, 1]], high[[0, 1]] = 0.2, 0.9
    ratio = [(sim.point_field(p, mid[None]) - perfect.point_field(p, mid[None]))[0]
             / np.sqrt(np.prod(perfect.thrust(p)[:2])) for p in (low, high)]
    assert ratio[1] > 2 * ratio[0]


def test_merging_jets_stands_for_the_familys_wider_candidate(reference, wb_setup):
    name, truth = candidate_for_hidden_effect(MergingJets())
    assert (name, truth) == ('jet_interaction_power', {'strength': 0.5, 'exponent': 0.75})
    geometry = wb_setup.geometry
    cands = {c.name: c for c in default_library().candidates(reference, geometry)}
    assert cands['jet_interaction_power'].family == cands['jet_interaction'].family == 'jet_interaction'
    assert cands['jet_interaction_power'].refine_always
    # with either form in the model, the family offers nothing more
    for form in ('jet_interaction', 'jet_interaction_power'):
        extended = apply_candidate(reference, cands[form], strength=0.2)
        assert _interaction_family(extended, geometry) == []


@pytest.mark.slow
def test_merging_jets_are_found_by_the_wider_candidate_and_nothing_wrong_is_named(
        diagnosed, reference, wb_setup, sim_data):
    # seed 5, 12 sweeps (conftest). Over seeds 100-109 it is found in 8/10 runs at 12 sweeps
    # and 5/10 at 24, nothing wrong named: the bridge's elongated shape, which no candidate
    # has, makes the strength differ from sweep to sweep in the others.
    d, (hidden,) = diagnosed('merging_jets')
    family = _family(reference, wb_setup.geometry)
    expected, truth = candidate_for_hidden_effect(hidden)
    assert d.verdict_ == 'found', d.summary()
    assert [t.candidate.name for t in d.steps_] == [expected], d.summary()
    assert {family[t.candidate.name] for t in d.steps_} == {'jet_interaction'}  # no wrong effect
    (step,) = d.steps_
    assert step.check is not None and step.check.passed, step.reasons
    # the thrust exponent is recovered; strength is not comparable (the candidate's bridge is
    # round and wider, so it needs less of it)
    exponent, std = step.params['exponent'], step.std['exponent'][0]
    assert abs(exponent - truth['exponent']) < 0.1
    assert (exponent - 0.5) / std > 3, (exponent, std)  # clearly not the one-form sqrt(T_i T_j)
    assert 0 < step.params['strength'] < 2 * truth['strength']
    assert 'faster than the geometric mean' in step.finding and 'thrust exponent' in step.finding
    assert d.final_rmse_ < 0.35 * d.baseline_rmse_
    # the one-form candidate lowers the held-out error too, but less, and ranks below
    first = d.ranking_
    assert first[0].candidate.name == expected
    one = next(t for t in first if t.candidate.name == 'jet_interaction')
    assert one.gain < first[0].gain

    # the library without the wider form: the one-form candidate does not hold across sweeps
    # alone on this data; beside a discrepancy model (the form it lacks) it does, and is named
    # as the right family with that said
    def one_form(model, geometry):
        return [c for c in _interaction_family(model, geometry) if c.name == 'jet_interaction']
    old = Library([one_form if k == 'jet_interaction' else f for k, f in FAMILIES.items()])
    data, _ = sim_data('merging_jets')
    d_old = Diagnosis(old).fit(reference, data, wb_setup.geometry)
    assert [t.candidate.name for t in d_old.steps_] == ['jet_interaction'], d_old.summary()
    (narrow,) = d_old.steps_
    assert narrow.check.p_value < 1e-3  # the spread alone, before the discrepancy
    assert narrow.check.beside is not None and narrow.check.beside.passed
    assert 'only with a discrepancy model beside it' in narrow.finding
    assert d_old.final_rmse_ > d.final_rmse_  # the wider form explains more
