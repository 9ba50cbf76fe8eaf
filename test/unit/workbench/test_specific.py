"""A change of chosen fans' jets is named only when it is specific to them: beside the same
change of every fan's jet it must keep most of what it explains (Diagnosis._not_specific)."""
import numpy as np
import pytest

from wind_shaper.model import ALL_FANS, FanShift, fan_landing, walk
from wind_shaper.sim import make_effect
from wind_shaper.workbench.commands import simulated_sweeps
from wind_shaper.workbench.diagnose import Diagnosis, every_fan_form
from wind_shaper.workbench.library import apply_candidate, default_library


def test_the_every_fan_form_moves_every_enabled_jet_by_one_shared_value(reference, wb_setup):
    cands = {c.name: c for c in default_library().candidates(reference, wb_setup.geometry)}
    every = every_fan_form(cands['fan_shift[CM]'], FanShift)
    assert every.name == every.label == 'fan_shift[all]' and every.family == 'fan_shift'
    model = apply_candidate(reference, every, shift=[0.02, -0.01])
    (node,) = [t for t in walk(model) if isinstance(t, FanShift) and t.group == ALL_FANS]
    assert node.shift.shape == (2,)  # one value for all
    fans = wb_setup.geometry.fans
    for j in np.flatnonzero(fans.enabled):
        np.testing.assert_allclose(fan_landing(node, j) - fan_landing(node.inner, j), [0.02, -0.01])


@pytest.mark.slow
def test_jets_that_spread_with_their_thrust_are_not_named_one_groups_width(wb_setup, reference):
    # seed 104 of bench/detection.py (--kinds fresh_mix): jets that spread with their thrust
    # beside a dead band read as "the higher group's footprint is 7 % wider", which held across
    # sweeps, on both sides of the footprint and at every load; every jet wider explains more
    sim = wb_setup.make_sim(seed=104, effects=[make_effect('jet_spreading'), make_effect('dead_band')])
    data = simulated_sweeps(sim, 12, seed=104)
    d = Diagnosis().fit(reference, data, wb_setup.geometry)
    assert not any(t.candidate.family == 'fan_width' for t in d.steps_)
    (refused,) = [t for t in d.demoted_ if t.candidate.name == 'fan_width[higher]']
    assert refused.reasons[-1].startswith("it is not specific to its fans: the same change of every "
                                          "fan's jet takes the held-out error down by")
    assert 'not specific to its fans' in d.summary()
    # switched off, the old finding comes back: the check is what refuses it
    d_off = Diagnosis(check_specific=False).fit(reference, data, wb_setup.geometry)
    assert 'fan_width[higher]' in [t.candidate.name for t in d_off.steps_]
