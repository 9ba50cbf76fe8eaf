"""A finding whose fitted parameter runs to the edge of its physical range is not named: the
family's form is stretched as far as it goes, so the physics is of another form."""
import pytest

from wind_shaper.model import FanElongation, JetInteractionPower
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
    # sweeps and at every load; only this check refuses it
    sim = wb_setup.make_sim(seed=103, effects=[make_effect('jet_spreading')])
    d = Diagnosis().fit(reference, simulated_sweeps(sim, 12, seed=103), wb_setup.geometry)
    assert d.steps_ == []
    (refused,) = [t for t in d.demoted_ if t.candidate.name == 'jet_interaction_power']
    (reason,) = refused.reasons  # it held across sweeps, on both sides and at every load
    assert reason.startswith('its exponent ran to the edge of the range its physics allows (2;')
    assert 'ran to the edge of the range its physics allows' in d.summary()
