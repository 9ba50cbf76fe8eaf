"""One candidate tried at one step of the diagnosis (``Trial``), and the helpers that read a
candidate's term and parameters out of a fitted model. Forces [N]."""
from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..model import Term, param_slices, term_label, walk
from .consistency import SweepCheck
from .fitting import FitResult
from .library import Candidate

__all__ = ['Trial', 'fit_mask', 'candidate_std', 'by_parameter', 'node_of']

_HELD = re.compile(r'(^|__)thrust(_higher|_lower)?\[0\]$')


def fit_mask(model: Term) -> np.ndarray:
    """Which free parameters a refit moves: all but the thrust polynomials' constant terms."""
    return np.array([not _HELD.search(n) for n in model.theta_names], dtype=bool)


def candidate_std(fit: FitResult, label: str) -> dict:
    """{parameter: standard errors} of the term ``label`` in a fit (Gauss-Newton)."""
    std_all = fit.std_of()
    for node, sl in param_slices(fit.model):
        if term_label(node) == label:
            return by_parameter(node, std_all[sl])
    return {}


def by_parameter(node: Term, flat) -> dict:
    """{parameter: its elements} of a term's free parameters laid out flat in ``flat`` (in
    ``model.theta`` order)."""
    out, i = {}, 0
    for h in node._free():
        out[h.name] = np.asarray(flat[i:i + h.size], float).tolist()
        i += h.size
    return out


def node_of(model: Term, label: str) -> Term | None:
    """The term labelled ``label`` in ``model`` (None when there is none)."""
    for n in walk(model):
        if term_label(n) == label:
            return n
    return None


@dataclass
class Trial:
    """One candidate tried at one step: its fitted model and parameters, the training BIC
    change, the held-out model error [N] and its relative drop, whether it passed the guard
    (and why not), and the finding in plain words. ``check``: the check across sweeps, the
    record the later checks write their refusal into; ``checks``: {check name: its
    ``checks.CheckResult``}, every check the trial went through (the guard, and for an effect
    the selection added every check of a finding)."""

    candidate: Candidate
    stage: str
    model: Term
    params: dict
    std: dict
    sse: float
    n: int
    k: int
    bic: float
    dbic: float
    heldout_rmse: float
    heldout_raw_rmse: float
    gain: float
    passed: bool = False
    reasons: list = field(default_factory=list)
    finding: str = ''
    check: SweepCheck | None = None
    gain_off: float | None = None  # held-out gain on the fans-off sweeps, when judged there
    checks: dict = field(default_factory=dict)
    # refused, but its family shows in the residual in a form the library lacks (``family_forms``)
    family_note: str = ''
    # the error bars as the selection had them, before the whole-model jackknife
    # (``uncertainty.reported_std``) widened them for the report
    selection_std: dict | None = None

    def to_json(self) -> dict:
        def clean(v):
            return np.round(np.asarray(v, float), 6).tolist()
        return {'candidate': self.candidate.name, 'family': self.candidate.family,
                'title': self.candidate.title, 'hypothesis': self.candidate.hypothesis,
                'stage': self.stage, 'params': {k: clean(v) for k, v in self.params.items()},
                'std': {k: clean(v) for k, v in self.std.items()},
                'train_rmse_N': float(np.sqrt(self.sse / self.n)), 'k': self.k,
                'bic': round(self.bic, 3), 'dbic': round(self.dbic, 3),
                'heldout_model_rmse_N': round(self.heldout_rmse, 6),
                'heldout_raw_rmse_N': round(self.heldout_raw_rmse, 6),
                'heldout_gain': round(self.gain, 4), 'passed': self.passed,
                'reasons': list(self.reasons), 'finding': self.finding,
                'across_sweeps': self.check.to_json() if self.check is not None else None,
                'checks': [r.to_json() for r in self.checks.values()],
                'family_note': self.family_note}
