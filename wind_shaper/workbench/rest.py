"""The diagnosis's stage after the checks: what the findings leave.

When the held-out model error left is still material (and the commands vary), a discrepancy
model of the residual, described in words (``discrepancy.describe_outside``), and a short
formula for it (``formula.fit_formula``); then a promising candidate short of the bar and the
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
    if (s.describe_outside and not case.low_spread
            and case.final_rmse >= s.material * case.noise_sd):
        case.discrepancy = describe_outside(case.final.model, case.train, case.heldout,
                                            case.train_sweeps.commands, case.geometry)
        case.formula = fit_formula(case.final.model, case.train, case.geometry).judge(
            case.final.model, case.heldout, min_gain=s.min_gain)
    case.undecided = undecided(case)
    return case
