"""Enough data? When a candidate is promising but below the guard's bar, how many more sweeps
would decide it.

A candidate is *promising* when the diagnosis did not report it (nor another of its family), and
at the step where the selection stopped for want of a passing candidate it lowers the held-out
model error by at least half the guard's ``min_gain`` and lowers the training BIC, and what it
fails is only the weight of evidence: its parameter's distance from "no effect" in standard
errors (``min_z``), the BIC drop (``min_dbic``), or the held-out drop itself. It is not
promising when it failed because there was nothing material to explain, the commands barely
varied, or it did not hold across sweeps (more sweeps of a patch do not make it physics), nor
when it is about a fan that a refused patch was about (the same residual, patched again), nor
when the diagnosis's discrepancy model (a pattern outside the library) lowers the held-out error
by more than 1.5 times what the candidate does (``RIVAL_SHARE``).

How many: with N sweeps, a parameter's standard error falls as 1/sqrt(N) and the BIC drop
grows as N, so N x max((min_z / z)^2, min_dbic / |dBIC|) sweeps would carry it over the bar,
if the effect is real and the model otherwise right. The held-out drop does not grow with N;
when it is short of ``min_gain``, a third more sweeps (one more held out in every three) is
the least that can show whether it holds. An effect the selection added but the check refused
only because too few training sweeps show it (``Diagnosis.check_min_sweeps``) is promising too:
the sweeps that let the check run are counted from the share of sweeps that show it. Which sweeps: ``suggest.suggest_sweeps`` with the
goal *separate*, written as a design for `wind-shaper collect`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .fitting import z_from_null

__all__ = ['Undecided', 'undecided', 'MAX_MORE']

#: More extra sweeps than this: the candidate explains too little to be decided by data.
MAX_MORE = 24
#: A candidate must lower the held-out error by at least this share of what the diagnosis's
#: discrepancy model (when offered) lowers it by: else it only patches a pattern the library lacks.
RIVAL_SHARE = 2 / 3


@dataclass(frozen=True)
class Undecided:
    """The promising candidate (a ``diagnose.Trial``), the sweeps recorded, how many more would
    decide it (``more``; None: more than ``MAX_MORE``), and why, in words."""

    trial: object
    recorded: int
    more: int | None
    why: str

    def text(self) -> str:
        t = self.trial
        head = (f'Promising but not decided: {t.candidate.title} lowers the held-out model error '
                f'{100 * t.gain:.0f} %, but {self.why}.')
        if self.more is None:
            return (head + f' More than {MAX_MORE} further sweeps would be needed to decide it: it '
                           f'explains too little of the residual for the data to tell.')
        return (head + f' About {self.more} more sweep(s) at varied commands ({self.recorded} now) '
                       f'would decide it, if it is real.')

    def to_json(self) -> dict:
        return {'candidate': self.trial.candidate.name, 'gain': round(self.trial.gain, 4),
                'recorded': self.recorded, 'more_sweeps': self.more, 'why': self.why}


def _too_few(d, floor: float) -> Undecided | None:
    """An effect the selection added that the check refused only because too few training
    sweeps show it: the sweeps that would let the check run (the same share of them showing it,
    every third held out)."""
    for t in sorted(d.demoted, key=lambda t: t.bic):
        c = t.check
        if c is None or not c.too_few or c.heldout_short or t.gain < floor:
            continue
        shows = max(int(c.informative.sum()), 1)
        train_needed = math.ceil(d.settings.check_min_sweeps * len(c.informative) / shows)
        recorded = len(d.train_sweeps) + len(d.test_sweeps)
        more = max(2, math.ceil(train_needed * 1.5) - recorded)
        return Undecided(t, recorded, more if more <= MAX_MORE else None,
                         f'only {shows} of the {len(c.informative)} training sweeps show it, too few '
                         f'to check that it holds across sweeps (needs {d.settings.check_min_sweeps})')
    return None


def undecided(d) -> Undecided | None:
    """The best promising candidate of a diagnosis's ``case.Case`` once its findings are checked
    and what they leave is described (see the module docstring), or None."""
    if not d.rankings or d.low_spread:
        return None
    # a candidate that explains much less than a pattern the library lacks is a patch of it
    disc = d.discrepancy
    floor = (RIVAL_SHARE * (1 - disc.heldout_after / disc.heldout_before)
             if disc is not None and disc.offered and disc.heldout_before > 0 else 0.0)
    few = _too_few(d, floor)
    if few is not None:
        return few
    if len(d.rankings) == len(d.selected):
        return None  # the selection stopped with nothing material left, not for want of evidence
    reported = {t.candidate.family for t in d.steps}
    patched = {f for t in d.demoted for f in t.candidate.fans}  # fans a refused patch was about
    pool = [t for t in d.rankings[-1] if t.stage == 'refined'
            and t.candidate.family not in reported and not t.passed
            and not set(t.candidate.fans) & patched
            and t.gain >= max(0.5 * d.settings.min_gain, floor) and t.dbic < 0]
    if not pool:
        return None
    best = min(pool, key=lambda t: t.bic)
    recorded = len(d.train_sweeps) + len(d.test_sweeps)
    factor, why = 1.0, []
    z = z_from_null(best.params, best.std, best.candidate.null)
    if z is not None and z < d.settings.min_z:
        factor = max(factor, (d.settings.min_z / max(z, 1e-3)) ** 2)
        why.append(f'its parameter is only {z:.1f} standard errors from no effect (needs {d.settings.min_z:g})')
    if best.dbic > -d.settings.min_dbic:
        factor = max(factor, d.settings.min_dbic / max(-best.dbic, 1e-3))
        why.append(f'the BIC falls only {-best.dbic:.1f} (needs {d.settings.min_dbic:g})')
    if best.gain < d.settings.min_gain:
        factor = max(factor, 4 / 3)
        why.append(f'the held-out drop is below {100 * d.settings.min_gain:.0f} %, which more held-out sweeps '
                   f'can confirm or refute')
    if not why:
        return None
    more = max(2, math.ceil(recorded * (factor - 1)))
    return Undecided(best, recorded, more if more <= MAX_MORE else None, '; '.join(why))
