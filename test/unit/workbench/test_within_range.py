"""A finding whose fitted parameter runs to the edge of its physical range is not named: the
family's form is stretched as far as it goes, so the physics is of another form."""
import numpy as np
import pytest

from wind_shaper.model import FanElongation, JetInteractionPower, find_term
from wind_shaper.sim import make_effect
from wind_shaper.workbench.commands import simulated_sweeps
from wind_shaper.workbench.consistency import check_within_range
from wind_shaper.workbench.diagnose import Diagnosis


def test_a_parameter_at_the_edge_of_its_range_is_refused(reference, wb_setup):
    fans = wb_setup.geometry.fans
    inside = JetInteractionPower(fans, reference, strength=0.1, width=1.5, exponent=0.8)
    assert check_within_range(inside, {'strength': 0.0}) == ''
    at_edge = JetInteractionPower(fans, reference, strength=0.1, width=1.5, exponent=2.0)
    why = check_within_range(at_edge, {'strength': 0.0})
    assert 'exponent ran to the edge' in why and '0.25 to 2' in why
    # an edge that is the no-effect value is not an edge: a round jet has elongation ratio 1
    round_jet = FanElongation(fans, reference, fan='LM2', ratio=1.0, angle=0.3)
    assert check_within_range(round_jet, {'ratio': 1.0}) == ''
    assert 'ratio' in check_within_range(FanElongation(fans, reference, fan='LM2', ratio=4.0),
                                         {'ratio': 1.0})


@pytest.mark.slow
def test_the_diagnosis_does_not_name_an_effect_fitted_at_its_edge(wb_setup, reference):
    # a jet that spreads with its thrust, seed 103 of bench/detection.py (--kinds fresh): read
    # as merging jets with the largest thrust exponent the family allows (2), which held across
    # sweeps and at every load
    sim = wb_setup.make_sim(seed=103, effects=[make_effect('jet_spreading')])
    data = simulated_sweeps(sim, 12, seed=103)
    without = Diagnosis(check_range=False).fit(reference, data, wb_setup.geometry)
    assert [t.candidate.name for t in without.steps_] == ['jet_interaction_power']
    node = find_term(without.final_.model, 'jet_interaction_power')
    assert np.isclose(float(np.ravel(node.exponent)[0]), 2.0, atol=0.01)
    checked = Diagnosis().fit(reference, data, wb_setup.geometry)
    assert checked.steps_ == []
    assert 'ran to the edge of the range its physics allows' in checked.summary()
