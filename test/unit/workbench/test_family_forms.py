"""Other forms of a family: a swirl whose angle follows another law than the candidate's is
found in its own form, or at least named at the family's level."""
from dataclasses import dataclass
from types import SimpleNamespace
from typing import ClassVar

import numpy as np
import pytest

from wind_shaper.model import SWIRL_LAWS, SwirlFollows, finite_difference_jacobian, term_from_dict
from wind_shaper.sim.effects import Swirl as SimSwirl
from wind_shaper.workbench import verdict
from wind_shaper.workbench.diagnose import Diagnosis
from wind_shaper.workbench.family_forms import FAMILY_WORDS
from wind_shaper.workbench.library import default_library
from wind_shaper.workbench.trial import Trial


@dataclass(frozen=True)
class SignSwirl(SimSwirl):
    """Swirl whose angle is a fixed turn whichever way the CW/CCW balance tips:
    theta = gain * tanh(b / 0.05) [rad] (the library's swirl is linear in b)."""

    gain: float = 0.15
    name: ClassVar[str] = 'sign_swirl'

    def angle(self, thrust, geometry):
        total = float(np.sum(thrust))
        if total <= 0:
            return 0.0
        return self.gain * float(np.tanh(np.dot(geometry.fans.spin_sign, thrust) / total / 0.05))


@pytest.mark.parametrize('law', sorted(SWIRL_LAWS))
def test_every_swirl_form_has_its_jacobian_and_round_trips(law, wb_setup, reference):
    fans = wb_setup.geometry.fans
    rng = np.random.default_rng(2)
    U, Z = rng.uniform(0.05, 0.9, (4, fans.n_fans)), rng.uniform(-0.2, 0.2, (4, 2))
    term = SwirlFollows(fans, reference, gain=0.3, follows=law)
    _, J = term._value_and_grad(U, Z, True)
    assert np.allclose(J, finite_difference_jacobian(term, U, Z), atol=1e-5)
    again = term_from_dict(term.to_dict(), fans)
    assert again.follows == law and np.allclose(again(U, Z), term(U, Z))


def test_the_forms_are_in_the_swirl_family_but_not_screened(wb_setup, reference):
    cands = default_library().candidates(reference, wb_setup.geometry)
    forms = [c for c in cands if c.other_form]
    assert {c.name for c in forms} == {f'swirl_{law}' for law in SWIRL_LAWS}
    assert {c.family for c in forms} == {'swirl'}


def test_a_refused_swirl_says_what_the_field_does_at_the_familys_level(wb_setup, reference):
    cand = default_library().get(reference, wb_setup.geometry, 'swirl')
    t = Trial(cand, 'refined', reference, {'gain': 0.2}, {'gain': [0.01]}, 1.0, 10, 1, 0.0, -20.0,
              0.1, 0.2, 0.4, reasons=['it does not hold across sweeps'])
    t.family_note = FAMILY_WORDS['swirl'] + ' (tried as well: ...)'
    case = SimpleNamespace(demoted=[t])
    text = verdict._demoted_text(case)
    assert 'but not as the swirl candidate has it' in text
    assert text.startswith('Partly explained by swirl rotation of the field (it lowers the held-out error 40 %)')


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_swirl_following_the_sign_of_the_balance_is_found_in_that_form(wb_setup, reference):
    effect = SignSwirl()
    from wind_shaper.workbench.commands import simulated_sweeps
    data = simulated_sweeps(wb_setup.make_sim(seed=101, effects=[effect]), 12, seed=101)
    d = Diagnosis().fit(reference, data, wb_setup.geometry)
    named = [t.candidate.name for t in d.steps_]
    assert named == ['swirl_sign'], d.summary()
    t = d.steps_[0]
    gain, sd = t.params['gain'], t.std['gain'][0]
    assert abs(gain - effect.gain) <= 2 * sd + 0.01
    assert 'not in the CW/CCW imbalance ratio' in d.summary()
