"""The diagnosis's stage after the checks: what the findings leave.

When the held-out model error left is still material and more than the noise by the test of
``noise_floor`` (and the commands vary), a discrepancy model of the residual, described in words
(``discrepancy.describe_outside``), and a short formula for it (``formula.fit_formula``). A
residual the noise explains is not described: any pattern read into it would be the noise's. A
model error that the test resolves but that is smaller than one sample's noise is described,
marked as below the noise (``DiscrepancyFit.below_noise``); then a promising candidate short of the bar and the
sweeps that would decide it (``enough.undecided``). Forces [N].
"""
from __future__ import annotations

from .discrepancy import describe_outside
from .enough import undecided
from .formula import fit_formula

__all__ = ['describe_rest']


def describe_rest(case):
    """Fill ``discrepancy``, ``formula`` and ``undecided`` of the ``Case``."""
    s = case.settings
    case.discrepancy = case.formula = None
    case.final_floor = case.floor_test(case.final.model) if case.steps else case.noise_floor
    if (s.describe_outside and not case.low_spread
            and case.final_rmse >= s.material * case.noise_sd and not case.final_floor.within):
        case.discrepancy = describe_outside(case.final.model, case.train, case.heldout,
                                            case.train_sweeps.commands, case.geometry)
        case.discrepancy.error_floor = case.final_floor.floor
        case.discrepancy.sample_noise = case.noise_sd
        case.discrepancy.below_noise = case.final_rmse < case.noise_sd
        case.formula = fit_formula(case.final.model, case.train, case.geometry).judge(
            case.final.model, case.heldout, min_gain=s.min_gain)
    case.undecided = undecided(case)
    return case
