"""Diagnosis: which physical effect is the model missing?

``Diagnosis(library).fit(model, sweeps, geometry)`` (an estimator: ``fit`` returns self, fitted
state ends in ``_``):

1. splits the sweeps into training and held-out sweeps (by sweep; at least ``MIN_SWEEPS`` = 6
   sweeps, else a FitError says to record more);
2. refits the model's free parameters on the training sweeps (``fit_mask``: every free
   parameter except the thrust polynomials' constant terms, which stay as commissioned: a fan
   at zero command gives no thrust, and a uniform offset is the background candidate's job);
3. forward selection, one effect per step: every candidate of the library is *screened*
   (fitted alone around the frozen current model, a few parameters, fast), the best
   ``refine`` by BIC on the training sweeps (and candidates marked ``refine_always``, whose
   effect the refitted polynomials partly absorb, such as a dead band) are *refined* (refitted
   together with the model), and the refined candidate with the lowest BIC that passes the
   guard is added; stop when none passes. Ranking by BIC uses every training sweep; the few
   held-out sweeps judge the result (the guard) rather than rank it.

The guard (what makes a finding): on the held-out sweeps the model error (noise removed, see
``metrics``) falls by at least ``min_gain`` (20 %); on the training sweeps the BIC falls by at
least ``min_dbic`` (10, "very strong" evidence); a parameter lies ``min_z`` (3) standard errors
from its no-effect value, the standard error being the larger of the Gauss-Newton one and the
delete-one-sweep jackknife (a term that only patches part of an unexplained residual fits
differently without each sweep); and the error before was *material*: at least ``material`` (half)
of the measurement noise (model error variance a quarter of the noise's). On data the model
already explains, the held-out error is already small against the noise and nothing is reported
("explained"). When the error is material and no candidate passes, the verdict is "unexplained"
and the report shows the residual's structure instead of forcing a term. An effect that shows
with every fan off (``Candidate.fans_off``: the background draft) may instead lower the model
error on the held-out fans-off sweeps by ``min_gain``, leaving the fans-on ones no worse: beside
physics the library lacks that dominates the fans-on residual (a draft that bends the plume),
a real offset is all of the fans-off sweeps' error but a small share of the whole.

The data must vary the commands: ``SweepSet.command_spread`` (per fan, the interquartile range of
its command over the sweeps; the median over the enabled fans) below ``min_spread`` (0.10, i.e.
10 % PWM) means the sweeps were taken at nearly one operating point (e.g. a converged shaping
run). There the held-out sweeps share the training sweeps' commands, so a term that merely
patches the residual at that operating point passes the held-out test too; no candidate is then
reported, and the verdict carries a warning saying what data to record instead. The forces
and the positions must be in step: ``sync.check_sync`` measures the lag between them, and the
verdict carries a warning when motion capture and the force sensor disagree.

Every effect the selection added is then checked by the registered checks (``checks``; each
finding's ``Trial.checks`` keeps every check's result): refitted sweep by sweep, it must keep one
value whatever the commands; then it must hold at its range's interior, be specific to what it
claims beside broader forms of the same change (``checks.specific.broader_forms``), hold on both
sides of its footprint and at every load, and not lean on the refitted thrust curves. One that
fails is demoted (``demoted_``: "partly explained by ..., but ...") and never named; ``steps_``
keeps the findings and ``selected_`` every step of the selection in order.

Reported parameters come from a refit on every training cell; their uncertainty is the larger of the
Gauss-Newton standard error and a delete-one-sweep jackknife (sweeps are the independent units).

Before any candidate is tried, the time checks (``time_checks``) ask whether the residual
depends on when a force was recorded: the fans-off sweeps' zero, the recording order, the time
since the commands changed, the time within a sweep. A fault in time (a drifting sensor zero,
fans still settling when a sweep starts) makes every candidate fit the wrong thing: with
``hold_on_time_fault`` no effect is then named, and the verdict ('time fault') says what was
found, what to do at the rig, and which repair of the recorded sweeps to give
(``time_repairs``: ``--zero-drift interpolate``, ``--skip-first S``).

The work is a line of stages, each taking and returning the one ``case.Case``:
``case.open_case`` (split, refit, noise) -> ``time_checks.check_time`` (faults in time) ->
``selection.select`` (screen and select) ->
``checks.check_findings`` (every check of each finding) -> ``family_forms.try_other_forms``
(the other forms of a family that explains much but does not hold) -> ``rest.describe_rest``
(what is left) -> ``verdict.word`` (the verdict). ``Diagnosis`` holds the settings, runs the stages and
exposes the case's results with a trailing underscore.
"""
from __future__ import annotations

from dataclasses import fields

from ..core.geometry import TunnelGeometry
from ..model import Term
from . import verdict
from .case import MIN_SWEEPS, Case, open_case
from .checks import CHECKS, Round, check_findings
from .checks.both_sides import ONE_JET_FAMILIES
from .checks.specific import SPECIFIC_FAMILIES, broader_forms, every_fan_form, mean_thrust_form
from .data import SweepSet
from .family_forms import try_other_forms
from .fitting import FitResult
from .library import Library
from .rest import describe_rest
from .selection import select
from .time_checks import check_time
from .trial import Trial, candidate_std, fit_mask
from .wording import _bic_text, _change_text, drop_text  # noqa: F401  (the words, as before)

__all__ = ['Diagnosis', 'Trial', 'fit_mask', 'candidate_std', 'drop_text', 'MIN_SWEEPS',
           'broader_forms', 'every_fan_form', 'mean_thrust_form', 'ONE_JET_FAMILIES',
           'SPECIFIC_FAMILIES']

#: The stages after ``open_case``, in order: each takes the ``Case`` and returns it.
STAGES = (check_time, select, check_findings, try_other_forms, describe_rest, verdict.word)
#: The stages that name effects or describe what they leave: skipped while a fault in time
#: holds the diagnosis (``Case.held``).
NAMING_STAGES = (select, check_findings, try_other_forms, describe_rest)

#: The case's fields a fitted ``Diagnosis`` exposes with a trailing underscore (``steps_``, ...).
_EXPOSED = tuple(f.name for f in fields(Case)
                 if f.name not in ('settings', 'current', 'current_rmse', 'data'))


class Diagnosis:
    """Forward selection of candidate effects with a guard (see the module docstring).

    library: ``Library`` (default: every family); cell [m]: grid of the training cell means;
    test_fraction / test: the held-out split (see ``SweepSet.split``); min_gain, min_dbic,
    min_z, material: the guard; max_effects: most effects added; refine: candidates refined
    per step; max_nfev: cap on a refit's iterations; noise_sd [N]: the measurement noise per
    sample, when the held-out sweeps are too short to estimate it (they must revisit places);
    min_spread [fraction of full PWM]: the least command spread (``SweepSet.command_spread``)
    at which findings are reported (0 switches the check off); check_sweeps: check every effect
    the selection added (``checks``; off: none of the checks below runs); check_min_sweeps:
    training sweeps that must show an effect for the check ``across_sweeps``; check_tolerance:
    the share of an effect's size a sweep's value may be off besides its standard error;
    check_space: cut a jet's shape through its footprint (``both_sides``); check_beside: give an
    effect whose values spread across sweeps a second check with a discrepancy model beside it
    (``beside_discrepancy``); check_load: every finding must hold whether the nearest fan runs
    high or low against the others (``every_load``); check_range: no finding's fitted parameter
    may run to the edge of its physical range (``within_range``); check_specific: a finding must
    keep most of what it explains beside broader forms of its change (``specific``: the same
    change of every fan's jet, every jet pushed from the axis, bridges following the mean
    thrust; share ``min_specific``); check_clocks: say when the forces and the positions are out
    of step (``sync.check_sync``, on the model as given); check_time: the time checks
    (``time_checks``), each fault significant at ``time_z`` (a normal quantile, 4 by default:
    a two-sided p of 6e-5, taken as a Student-t with few sweeps) and material (``material`` times the
    noise); hold_on_time_fault: name no effect while a time check finds a fault.
    """

    def __init__(self, library: Library | None = None, *, cell: float = 0.04,
                 test_fraction: float = 1 / 3, test=None, min_gain: float = 0.2,
                 min_dbic: float = 10.0, min_z: float = 3.0, material: float = 0.5,
                 max_effects: int = 3, refine: int = 2, max_nfev: int = 40,
                 noise_sd: float | None = None, min_spread: float = 0.10,
                 check_sweeps: bool = True, describe_outside: bool = True,
                 check_min_sweeps: int = 4, check_tolerance: float = 0.1,
                 check_space: bool = True, check_beside: bool = True, check_load: bool = True,
                 check_range: bool = True, check_specific: bool = True,
                 min_specific: float = 0.5, check_clocks: bool = True,
                 check_time: bool = True, time_z: float = 4.0, hold_on_time_fault: bool = True):
        self.library = library
        self.cell, self.test_fraction, self.test = cell, test_fraction, test
        self.min_gain, self.min_dbic, self.min_z, self.material = min_gain, min_dbic, min_z, material
        self.min_spread = min_spread
        self.max_effects, self.refine, self.max_nfev = max_effects, refine, max_nfev
        self.noise_sd = noise_sd
        self.check_sweeps = check_sweeps
        self.describe_outside = describe_outside
        self.check_min_sweeps = check_min_sweeps
        self.check_tolerance = check_tolerance
        self.check_space = check_space
        self.check_beside = check_beside
        self.check_load = check_load
        self.check_range = check_range
        self.check_clocks = check_clocks
        self.check_time, self.time_z, self.hold_on_time_fault = check_time, time_z, hold_on_time_fault
        self.check_specific, self.min_specific = check_specific, min_specific

    # -- fit ----------------------------------------------------------------------------------
    def fit(self, model: Term, data: SweepSet, geometry: TunnelGeometry) -> 'Diagnosis':
        """Run the stages on ``model`` and the sweeps ``data`` of the tunnel ``geometry``."""
        case = open_case(self, model, data, geometry)
        for stage in STAGES:
            if case.held and stage in NAMING_STAGES:
                continue
            case = stage(case)
        self.case_ = case
        for name in _EXPOSED:
            setattr(self, name + '_', getattr(case, name))
        return self

    # -- results ------------------------------------------------------------------------------
    @property
    def findings_(self) -> list[str]:
        return [t.finding for t in self.steps_]

    @property
    def ranking_(self) -> list[Trial]:
        """The first step's ranked table (every candidate against the refitted model)."""
        return self.rankings_[0] if self.rankings_ else []

    def time_warning(self) -> str:
        """What the time checks found and what to do ('' when the sweeps do not depend on when
        they were recorded)."""
        return verdict.time_warning(self.case_)

    def spread_warning(self) -> str:
        """What is wrong with data whose commands barely vary, and what to record instead
        ('' when they vary enough)."""
        return verdict.spread_warning(self.case_)

    def sync_warning(self) -> str:
        """What to check when the forces and the positions look out of step ('' when not)."""
        return self.sync_.text() if self.sync_ is not None else ''

    def summary(self) -> str:
        """The verdict in plain words (with the warnings about data whose commands barely vary
        and about forces and positions out of step)."""
        return verdict.summary_text(self.case_)

    def checks_text(self) -> str:
        """Every check and its result for each effect the selection added, in words."""
        return verdict.checks_text(self.case_)

    def to_json(self) -> dict:
        return verdict.to_json(self.case_)

    # -- single stages on the fitted case, for tests and notebooks -------------------------------
    def _rebuild(self, steps: list) -> FitResult:
        """The baseline with the effects of ``steps`` added, refitted (``Case.rebuild``)."""
        return self.case_.rebuild(steps)

    def _leans_on_curves(self, kept: list):
        """(finding, why) for the finding of ``kept`` that leans most on the refitted thrust
        curves (the check ``thrust_curves``), or None."""
        results = CHECKS['thrust_curves'].measure(self.case_, Round(kept, None, []))
        refused = {i: r for i, r in results.items() if r.passed is False}
        if not refused:
            return None
        i = CHECKS['thrust_curves'].worst(refused)
        return kept[i], refused[i].why
