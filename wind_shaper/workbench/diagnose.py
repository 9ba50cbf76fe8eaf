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

Every effect the selection added is then checked across sweeps (``consistency``): refitted sweep
by sweep, it must keep one value whatever the commands; then it must hold at its range's
interior, be specific to what it claims beside broader forms of the same change
(``broader_forms``), hold on both sides of its footprint and at every load, and not lean on the
refitted thrust curves. One that fails is demoted (``demoted_``:
"partly explained by ..., but ...") and never named; ``steps_`` keeps the findings and
``selected_`` every step of the selection in order.

Reported parameters come from a refit on every training cell; their uncertainty is the larger of the
Gauss-Newton standard error and a delete-one-sweep jackknife (sweeps are the independent units).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field, replace

import numpy as np

from ..model import (ALL_FANS, FanPush, FanShift, FanWrapper, JetInteraction, Term, param_slices,
                     term_label)
from ..core.geometry import TunnelGeometry
from .consistency import (SweepCheck, check_across_load, check_across_space, check_across_sweeps,
                          check_beside_discrepancy, check_within_range)
from .data import FitData, SweepSet
from .discrepancy import SCALE_FEATURES, describe_outside, outside_text
from .enough import undecided
from .formula import fit_formula, formula_text
from .errors import FitError
from .fitting import FitResult, Frozen, bic, fit_model, jackknife_std, z_from_null
from .library import Candidate, Library, apply_candidate, default_library
from .metrics import HeldOut
from .sync import check_sync
from .wording import _bic_text, _change_text, drop_text, pct_text, values_text

__all__ = ['Diagnosis', 'Trial', 'fit_mask', 'candidate_std', 'drop_text', 'MIN_SWEEPS']

#: Fewer sweeps leave too few held out (every third) to judge a finding.
MIN_SWEEPS = 6

_HELD = re.compile(r'(^|__)thrust(_higher|_lower)?\[0\]$')


#: The candidate families that change one fan's jet (checked on both sides of its footprint).
ONE_JET_FAMILIES = ('fan_gain', 'fan_shift', 'fan_width', 'fan_elongation', 'fan_shape')
#: Families whose findings must be specific to what they claim (``Diagnosis._not_specific``):
#: chosen fans' jets, and the pairs of neighbouring jets.
SPECIFIC_FAMILIES = ('fan_shift', 'fan_width', 'fan_elongation', 'fan_shape', 'jet_interaction')


def every_fan_form(candidate: Candidate, cls: type, title: str = 'every fan alike') -> Candidate:
    """``candidate``'s change applied to every enabled fan with one shared value: a term of
    class ``cls`` (a ``FanWrapper``) with ``group='all'``, placed as the candidate is."""
    kind = cls.kind
    return replace(candidate, name=f'{kind}[{ALL_FANS}]', label=f'{kind}[{ALL_FANS}]', family=kind,
                   title=f'{candidate.title} ({title})', fans=(),
                   make=lambda m, **p: cls(m.fans, m, group=ALL_FANS, **p))


def mean_thrust_form(candidate: Candidate) -> Candidate:
    """The jet-interaction ``candidate``'s bridges filled by the tunnel's mean thrust instead
    of each pair's (``JetInteraction(follows='mean')``), placed as the candidate is."""
    return replace(candidate, name='jet_interaction[mean]', label='jet_interaction', family='jet_interaction',
                   title=f'{candidate.title} (following the mean thrust)',
                   make=lambda m, **p: JetInteraction(m.fans, m, follows='mean', **p))


def broader_forms(candidate: Candidate, node: Term, fans) -> list:
    """[(broader form, its start values, words)] a finding is checked beside: the same kind of
    change without what makes the finding specific, started from the finding's values.

    A change of chosen fans' jets: the same change of every jet with one shared value; a
    landing offset also every jet moved outwards from the axis by one distance (jets that cling
    to the wall or are drawn to the middle move each in its own direction, which one shared
    vector cannot follow), started from the finding's outward part. A jet interaction: the
    same bridges filled by the tunnel's mean thrust rather than by each pair's thrusts."""
    if isinstance(node, JetInteraction):
        if node.follows == 'mean':
            return []
        start = {'strength': node.strength, 'width': node.width}
        return [(mean_thrust_form(candidate), start,
                 "the same bridges between the jets following the tunnel's mean thrust instead of "
                 "each pair's thrusts")]
    if not isinstance(node, FanWrapper) or node.group == ALL_FANS:
        return []
    out = [(every_fan_form(candidate, type(node)), candidate.params(node),
            "the same change of every fan's jet")]
    if isinstance(node, FanShift) and node.fan is not None:
        hubs = np.asarray(fans.positions, float)[[fans.index(name) for name in node.fan]]
        radius = np.hypot(hubs[:, 0], hubs[:, 1])
        shifts = node.shift.reshape(-1, 2)
        outward = [float(s @ h / r) for s, h, r in zip(shifts, hubs, radius) if r > 1e-6]
        if outward:
            (bounds,) = [h.bounds for h in FanPush.hypers if h.name == 'push']
            push = float(np.clip(np.mean(outward), *bounds))
            out.append((every_fan_form(candidate, FanPush, 'every jet pushed from the axis alike'),
                        {'push': push}, 'every jet moved outwards from the axis by one distance'))
    return out


def fit_mask(model: Term) -> np.ndarray:
    """Which free parameters a refit moves: all but the thrust polynomials' constant terms."""
    return np.array([not _HELD.search(n) for n in model.theta_names], dtype=bool)


def candidate_std(fit: FitResult, label: str) -> dict:
    """{parameter: standard errors} of the term ``label`` in a fit (Gauss-Newton)."""
    std_all = fit.std_of()
    for node, sl in param_slices(fit.model):
        if term_label(node) == label:
            return _by_parameter(node, std_all[sl])
    return {}


def _by_parameter(node: Term, flat) -> dict:
    """{parameter: its elements} of a term's free parameters laid out flat in ``flat`` (in
    ``model.theta`` order)."""
    out, i = {}, 0
    for h in node._free():
        out[h.name] = np.asarray(flat[i:i + h.size], float).tolist()
        i += h.size
    return out


@dataclass
class Trial:
    """One candidate tried at one step: its fitted model and parameters, the training BIC
    change, the held-out model error [N] and its relative drop, whether it passed the guard
    (and why not), and the finding in plain words."""

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
                'across_sweeps': self.check.to_json() if self.check is not None else None}


class Diagnosis:
    """Forward selection of candidate effects with a guard (see the module docstring).

    library: ``Library`` (default: every family); cell [m]: grid of the training cell means;
    test_fraction / test: the held-out split (see ``SweepSet.split``); min_gain, min_dbic,
    min_z, material: the guard; max_effects: most effects added; refine: candidates refined
    per step; max_nfev: cap on a refit's iterations; noise_sd [N]: the measurement noise per
    sample, when the held-out sweeps are too short to estimate it (they must revisit places);
    min_spread [fraction of full PWM]: the least command spread (``SweepSet.command_spread``)
    at which findings are reported (0 switches the check off); check_sweeps: check every effect
    the selection added sweep by sweep before naming it (``consistency``); check_min_sweeps:
    training sweeps that must show an effect for that check; check_tolerance: the share of an
    effect's size a sweep's value may be off besides its standard error; check_space: cut a
    jet's shape through its footprint (``_one_sided``); check_beside: give an effect whose
    values spread across sweeps a second check with a discrepancy model beside it
    (``_beside_discrepancy``); check_load: every finding must hold whether the nearest fan runs
    high or low against the others (``_off_load``); check_range: no finding's fitted parameter
    may run to the edge of its physical range (``_at_edge``); check_specific: a finding must
    keep most of what it explains beside broader forms of its change (``broader_forms``: the
    same change of every fan's jet, every jet pushed from the axis, bridges following the mean
    thrust; ``_not_specific``, share ``min_specific``); check_clocks: say when the forces and the
    positions are out of step (``sync.check_sync``, on the model as given).
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
                 min_specific: float = 0.5, check_clocks: bool = True):
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
        self.check_specific, self.min_specific = check_specific, min_specific

    # -- the steps ----------------------------------------------------------------------------
    def _evaluate(self, model: Term) -> tuple[float, float]:
        ev = self.heldout_.evaluate(model)
        return ev['model_rmse'], ev['raw'].rmse

    def _trial(self, cand, stage, fit: FitResult, current: FitResult, current_rmse, std=None):
        node = None
        for n in _nodes(fit.model):
            if term_label(n) == cand.label:
                node = n
                break
        if node is None:
            raise FitError(f'candidate {cand.name} did not place its term {cand.label} in the model')
        held, raw = self._evaluate(fit.model)
        k = current.k + fit.k if stage == 'screened' else fit.k
        if fit.n == len(self.train_):
            sse = fit.sse
        else:  # fitted on the screening cells: score on every training cell
            r = fit.model(self.train_.U, self.train_.Z) - self.train_.y
            sse = float(r @ r)
        n = len(self.train_)
        b = bic(sse, n, k)
        gain = 1.0 - held / current_rmse if current_rmse > 0 else 0.0
        return Trial(cand, stage, fit.model, cand.params(node),
                     std if std is not None else candidate_std(fit, cand.label),
                     sse, n, k, b, b - current.bic, held, raw, gain), node

    def _screen(self, cand: Candidate, current: FitResult, current_rmse: float, frozen: Frozen):
        best = None
        for start in cand.starts:
            model = apply_candidate(frozen, cand, **start)
            fit = fit_model(model, self.screen_, max_nfev=15, ftol=1e-4, xtol=1e-5)
            if best is None or fit.sse < best.sse:
                best = fit
        return self._trial(cand, 'screened', best, current, current_rmse)[0]

    def _refine(self, trial: Trial, current: FitResult, current_rmse: float, data: FitData | None = None,
                max_nfev: int | None = None):
        """Refit the candidate together with the model's free parameters (on the screening
        cells unless ``data`` is given; the accepted one is polished on every training cell)."""
        cand = trial.candidate
        model = apply_candidate(current.model, cand, **trial.params)
        fit = fit_model(model, data if data is not None else self.screen_, free=fit_mask(model),
                        max_nfev=max_nfev or self.max_nfev)
        out, node = self._trial(cand, 'refined', fit, current, current_rmse)
        return out, fit

    def _gain_with_fans_off(self, t: Trial, current_model: Term) -> float | None:
        """For an effect that shows with every fan off (a background draft): the share of the
        held-out fans-off sweeps' model error it removes, when it leaves the fans-on held-out
        sweeps no worse; else None. With the fans on, physics the library lacks (a draft that
        bends the plume) can carry most of the residual, so an offset that is all of the
        fans-off sweeps' error removes only a small share of the whole."""
        if not (t.candidate.fans_off and self.heldout_off_ is not None and current_model is not None):
            return None
        off, on = self.heldout_off_
        before = off.evaluate(current_model)['model_rmse']
        if before <= 0 or on.evaluate(t.model)['model_rmse'] > on.evaluate(current_model)['model_rmse']:
            return None
        return float(1.0 - off.evaluate(t.model)['model_rmse'] / before)

    def _guard(self, t: Trial, current_rmse: float, current_model: Term | None = None) -> None:
        reasons = []
        if self.low_spread_:
            reasons.append('not identifiable: the sweeps\' commands barely vary (see the verdict)')
        if current_rmse < self.material * self.noise_sd_:
            reasons.append(f'nothing material to explain (held-out model error {current_rmse:.3f} N '
                           f'< {self.material:.2f} x noise {self.noise_sd_:.3f} N)')
        t.gain_off = self._gain_with_fans_off(t, current_model) if t.gain < self.min_gain else None
        if t.gain < self.min_gain and (t.gain_off is None or t.gain_off < self.min_gain):
            off = '' if t.gain_off is None else f', on the fans-off sweeps {_change_text(t.gain_off)}'
            reasons.append(f'held-out error {_change_text(t.gain)}{off} (needs to fall >= '
                           f'{100 * self.min_gain:.0f} %)')
        if t.dbic > -self.min_dbic:
            reasons.append(f'BIC {_bic_text(t.dbic)} (needs to fall >= {self.min_dbic:g})')
        z = z_from_null(t.params, t.std, t.candidate.null)
        if z is not None and z < self.min_z:
            reasons.append(f'parameter only {z:.1f} standard errors from no effect (< {self.min_z:g})')
        t.reasons = reasons
        t.passed = not reasons

    # -- fit ----------------------------------------------------------------------------------
    def fit(self, model: Term, data: SweepSet, geometry: TunnelGeometry) -> 'Diagnosis':
        data.check_fans(geometry.fans.names)
        if len(data) < MIN_SWEEPS:
            raise FitError(f'{len(data)} sweeps are too few for a diagnosis: it holds every third '
                           f'sweep out to judge the findings and needs at least {MIN_SWEEPS} (8-12 '
                           f'are better); record more at varied commands, e.g. `wind-shaper collect '
                           f'--design lhs:12 --out NAME`, and pool them with --data')
        if model.n_fans != geometry.fans.n_fans:
            raise FitError(f'the model is for {model.n_fans} fans, the tunnel has {geometry.fans.n_fans}')
        library = self.library or default_library()
        self.geometry_ = geometry
        self.command_spread_ = data.command_spread(geometry.fans.enabled)
        self.low_spread_ = self.command_spread_['median'] < self.min_spread
        self.train_sweeps_, self.test_sweeps_ = data.split(self.test_fraction, self.test)
        self.train_ = self.train_sweeps_.fit_data(self.cell)
        self.screen_ = self.train_.subset(slice(None, None, 2))  # screening needs only a ranking
        self.heldout_ = HeldOut(self.test_sweeps_)
        self.heldout_off_ = self._fans_off_split(geometry)
        base = fit_model(model, self.train_, free=fit_mask(model), max_nfev=self.max_nfev)
        self.model_, self.baseline_ = model, base
        self.noise_sd_ = (float(self.noise_sd) if self.noise_sd is not None
                          else self.heldout_.estimate_noise(base.model))
        if not np.isfinite(self.noise_sd_):
            raise FitError('the held-out sweeps revisit too few places to estimate the measurement '
                           'noise: record sweeps of 1000 samples (the default tour crosses the disc more '
                           'than once) or give the noise per sample (noise_sd, --noise-sd)')
        self.heldout_.noise_sd = self.noise_sd_
        self.baseline_rmse_, self.baseline_raw_ = self._evaluate(base.model)
        self.sync_ = check_sync(base.model, data) if self.check_clocks else None
        self.library_ = library
        self.steps_, self.rankings_, current, current_rmse = self._select(base, self.baseline_rmse_)
        self.demoted_ = []
        self.selected_ = list(self.steps_)  # every step of the selection, in order
        if self.check_sweeps and self.steps_:
            current = self._check_findings()
            current_rmse = self._evaluate(current.model)[0]
        self.final_ = current
        self.final_rmse_ = current_rmse
        self.final_raw_ = self._evaluate(current.model)[1]
        if self.steps_:
            self.verdict_ = 'found'
        elif self.baseline_rmse_ < self.material * self.noise_sd_:
            self.verdict_ = 'explained'
        else:
            self.verdict_ = 'unexplained'
        # what the library leaves: a discrepancy model of the residual, described, and a short
        # formula for it; then a promising candidate, which must explain more than a patch would
        self.discrepancy_ = self.formula_ = None
        if (self.describe_outside and not self.low_spread_
                and self.final_rmse_ >= self.material * self.noise_sd_):
            self.discrepancy_ = describe_outside(self.final_.model, self.train_, self.heldout_,
                                                 self.train_sweeps_.commands, geometry)
            self.formula_ = fit_formula(self.final_.model, self.train_, geometry).judge(
                self.final_.model, self.heldout_, min_gain=self.min_gain)
        self.undecided_ = undecided(self)
        return self

    def _fans_off_split(self, geometry):
        """(held-out fans-off sweeps, the other held-out sweeps) as ``HeldOut`` sets, each with
        its own noise (turbulence grows with the thrust), or None when no held-out sweep has
        every fan off."""
        commands = self.test_sweeps_.commands[:, geometry.fans.enabled]
        off = [i for i, u in enumerate(commands) if np.all(np.abs(u) < 1e-6)]
        on = [i for i in range(len(commands)) if i not in off]
        if not off or not on:
            return None
        return HeldOut(self.test_sweeps_[off]), HeldOut(self.test_sweeps_[on])

    def _select(self, current: FitResult, current_rmse: float):
        """Forward selection from ``current`` (its held-out model error ``current_rmse`` [N]):
        add the refined candidate with the lowest BIC that passes the guard, up to
        ``max_effects``. Returns (steps, rankings, final fit, its held-out model error)."""
        geometry = self.geometry_
        steps, rankings = [], []
        accepted: set[str] = set()
        for _ in range(self.max_effects):
            if current_rmse < self.material * self.noise_sd_:
                break
            cands = [c for c in self.library_.candidates(current.model, geometry)
                     if c.name not in accepted]
            if not cands:
                break
            frozen = Frozen(current.model)
            screened = sorted((self._screen(c, current, current_rmse, frozen) for c in cands),
                              key=lambda t: t.bic)
            picks = screened[:self.refine] + [t for t in screened[self.refine:] if t.candidate.refine_always]
            refined = []
            for t in picks:
                trial, fit = self._refine(t, current, current_rmse)
                self._guard(trial, current_rmse, current.model)
                if trial.passed:  # judge the parameter by its sweep-to-sweep spread as well
                    trial.std = self._uncertainty(trial, current, fit)
                    self._guard(trial, current_rmse, current.model)
                refined.append((trial, fit))
            rest = [t for t in screened if all(t is not p for p in picks)]
            for t in rest:
                self._guard(t, current_rmse)
                if t.passed:  # screened only: may not be reported without a refit
                    t.passed = False
                    t.reasons = ['not among the best refined candidates']
            ranking = sorted([t for t, _ in refined], key=lambda t: t.bic) + rest
            rankings.append(ranking)
            passing = [(t, f) for t, f in refined if t.passed]
            if not passing:
                break
            best, fit = min(passing, key=lambda tf: tf[0].bic)
            # a wider form of a family (swirl growing faster than the imbalance, a free thrust
            # exponent) must earn its extra parameters as an effect earns its place: by the BIC
            # bar over the narrower form, when that passes too
            narrower = [(t, f) for t, f in passing if t.candidate.family == best.candidate.family
                        and t.k < best.k and t.bic < best.bic + self.min_dbic]
            if narrower:
                best, fit = min(narrower, key=lambda tf: (tf[0].k, tf[0].bic))
            polished, fit = self._refine(best, current, current_rmse, data=self.train_, max_nfev=15)
            polished.std = self._uncertainty(polished, current, fit)
            polished.passed, polished.reasons, polished.check = True, [], best.check
            polished.gain_off = best.gain_off
            ranking[ranking.index(best)] = polished
            best = polished
            best.finding = best.candidate.describe(_node(fit.model, best.candidate.label), best.std)
            steps.append(best)
            accepted.add(best.candidate.name)
            current, current_rmse = fit, best.heldout_rmse
        return steps, rankings, current, current_rmse

    def _rebuild(self, steps: list) -> FitResult:
        """The baseline model with the effects of ``steps`` added, refitted on the training
        sweeps."""
        model = self.baseline_.model
        for t in steps:
            model = apply_candidate(model, t.candidate, **t.params)
        if not steps:
            return self.baseline_
        return fit_model(model, self.train_, free=fit_mask(model), max_nfev=15)

    def _check_findings(self) -> FitResult:
        """Check every effect the selection added across sweeps, each in the model with all
        the others (an effect checked before a second real one is in the model would be
        perturbed by it); once all hold across sweeps, a change of a jet's shape must hold on
        both sides of its footprint and every effect against the thrust curves as commissioned.
        Demote the one that fails worst and check the rest again, until all pass. Returns the
        final fit; ``steps_`` keeps what passed, ``demoted_`` the rest."""
        kept = list(self.steps_)
        while kept:
            final = self._rebuild(kept)
            failed, withouts = [], []
            for t in kept:
                without = self._rebuild([o for o in kept if o is not t])
                withouts.append(without)
                t.check = check_across_sweeps(final.model, t.candidate.label, t.candidate.null,
                                              self.train_, self.heldout_, without.model,
                                              min_sweeps=self.check_min_sweeps,
                                              tolerance=self.check_tolerance)
                self._beside_discrepancy(t, final, without)
                if not t.check.passed:
                    failed.append(t)
            if failed:
                worst = min(failed, key=lambda t: t.check.p_value)
            else:
                refused = (self._at_edge(final, kept) or self._not_specific(final, kept, withouts)
                           or self._one_sided(final, kept, withouts)
                           or self._off_load(final, kept, withouts) or self._leans_on_curves(kept))
                if refused is None:
                    break
                worst, reason = refused
                # a patch of something else, like a value that does not hold across sweeps:
                # never promising, and the verdict says the physics is likely outside
                worst.check.passed, worst.check.spread = False, True
                worst.check.reasons.append(reason)
            worst.passed, worst.reasons = False, list(worst.check.reasons)
            self.demoted_.append(worst)
            kept.remove(worst)
        final = self._rebuild(kept)
        for t in kept:  # the parameters as the final model has them
            node = _node(final.model, t.candidate.label)
            t.params = t.candidate.params(node)
            t.finding = (t.candidate.describe(node, t.std) + _fans_off_text(t, self.min_gain)
                         + _beside_text(t, final.model))
        self.steps_ = kept
        return final

    def _beside_discrepancy(self, t: Trial, final: FitResult, without: FitResult) -> None:
        """Give an effect whose values spread across sweeps its second chance: the same check
        with a discrepancy model beside it (``consistency.check_beside_discrepancy``), for a
        real effect perturbed by physics the library lacks. Only the spread is forgiven: an
        effect too few sweeps show, or that helps too few held-out sweeps, stays refused. The
        discrepancy is tried as bumps x command features, then with the model's own scale
        beside them (``discrepancy.SCALE_FEATURES``); the first form it holds beside is kept."""
        c = t.check
        if not (self.check_beside and c.spread and not c.heldout_short):
            return
        for scale in ((), SCALE_FEATURES):  # bumps only; then with the model's own scale too
            c.beside = check_beside_discrepancy(final.model, t.candidate.label, t.candidate.null,
                                                self.train_, self.heldout_, without.model,
                                                self.geometry_, c.informative,
                                                tolerance=self.check_tolerance, scale_features=scale,
                                                values_before=c.values[c.informative])
            if c.beside.passed:
                break
        if c.beside.passed:
            c.passed, c.spread, c.reasons = True, False, []
        else:
            c.reasons += c.beside.reasons

    def _at_edge(self, final: FitResult, kept: list):
        """(finding, why) for the first finding whose fitted parameters ran to the edge of
        their physical range (``consistency.check_within_range``), or None."""
        if not self.check_range:
            return None
        for t in kept:
            why = check_within_range(_node(final.model, t.candidate.label), t.candidate.null)
            if why:
                return t, why
        return None

    def _not_specific(self, final: FitResult, kept: list, withouts: list):
        """(finding, why) for the first finding that is not specific to what it claims, or None:
        a change of chosen fans' jets (their landing point, width, elongation or shape) not
        specific to those fans, or a jet interaction not specific to its pairs of jets.

        Physics the library lacks that moves or widens every jet (a draft across the tunnel,
        jets that spread with their thrust) is partly explained by moving or widening one fan
        or one group, and that finding holds across sweeps, on both sides of the footprint and
        at every load. A real change of one jet is specific: the same change of every fan's jet
        (``group='all'``, one shared value, refitted from the finding's values) explains little
        of it, so beside that form the finding still lowers the held-out error by at least
        ``min_specific`` of what it lowers it alone. A landing offset is also checked beside
        every jet moved outwards from the axis by one distance (``FanPush``): jets that cling to
        the wall move each in its own direction, which one shared vector cannot follow. A jet
        interaction is checked beside the same bridges filled by the tunnel's mean thrust: a
        leak or a recirculation that follows the tunnel's pressure fits as wide, weak bridges,
        whose gain then owes nothing to each pair's thrusts (``broader_forms``). A gain is not
        checked: the same gain for every fan is the refitted thrust curves."""
        if not self.check_specific:
            return None
        for t, without in zip(kept, withouts):
            if t.candidate.family not in SPECIFIC_FAMILIES:
                continue
            node = _node(final.model, t.candidate.label)
            forms = broader_forms(t.candidate, node, self.geometry_.fans)
            if not forms:
                continue
            error_without = self._evaluate(without.model)[0]
            alone = 1.0 - self._evaluate(final.model)[0] / error_without
            if alone <= 0:
                continue
            for every, start, words in forms:
                shared = apply_candidate(without.model, every, **start)
                shared = fit_model(shared, self.train_, free=fit_mask(shared), max_nfev=15)
                both = apply_candidate(shared.model, t.candidate, **t.params)
                both = fit_model(both, self.train_, free=fit_mask(both), max_nfev=15)
                before = self._evaluate(shared.model)[0]
                beside = 1.0 - self._evaluate(both.model)[0] / before if before > 0 else 0.0
                if beside < self.min_specific * alone:
                    every_alone = 1.0 - before / error_without
                    what = 'its pairs of jets' if isinstance(node, JetInteraction) else 'its fans'
                    return t, (f'it is not specific to {what}: a broader form, {words}, takes the '
                               f'held-out error down by {pct_text(every_alone)} (this finding alone: '
                               f'{pct_text(alone)}), and with this finding added beside it the held-out error '
                               f'{_change_text(beside)}; '
                               f'a change of the whole flow, such as a draft, jets that spread with their '
                               f'thrust or cling to the wall, or a leak that follows the tunnel\'s pressure, '
                               f'shows partly as this finding')
        return None

    def _one_sided(self, final: FitResult, kept: list, withouts: list):
        """(finding, why) for the first change of one jet (its gain, landing point, width or
        shape), or effect that held only beside a discrepancy, that does not hold on both sides
        of its footprint (``consistency.check_across_space``), or None. A patch that passes a
        fixed share of the flow beside a hub, or a stand's wake across one jet, changes that jet
        the same way in every sweep, so the check across sweeps cannot refuse it; the two sides
        of a real change of that jet agree. Other whole-tunnel effects are not cut: they would
        fail for any pattern the library lacks on one side (swirl beside a warm wall)."""
        if not self.check_space:
            return None
        for t, without in zip(kept, withouts):
            rescued = t.check.beside is not None and t.check.beside.passed
            if t.candidate.family not in ONE_JET_FAMILIES and not rescued:
                continue
            why = check_across_space(final.model, t.candidate.label, t.candidate.null, self.train_,
                                     without.model, tolerance=self.check_tolerance)
            if why:
                return t, why
        return None

    def _off_load(self, final: FitResult, kept: list, withouts: list):
        """(finding, why) for the first finding whose value differs where the nearest fan runs
        high and where it runs low against the others (``consistency.check_across_load``), or
        None. A term of another form than the physics (a boundary layer for a return flow
        down the wall that follows the whole tunnel's thrust) holds in every sweep, since each
        sweep averages strong and weak jets, but not at every load."""
        if not self.check_load:
            return None
        for t, without in zip(kept, withouts):
            why = check_across_load(final.model, t.candidate.label, t.candidate.null, self.train_,
                                    without.model, self.geometry_, tolerance=self.check_tolerance)
            if why:
                return t, why
        return None

    def _leans_on_curves(self, kept: list, min_share: float = 0.5):
        """(finding, why) for the finding that leans most on the refitted thrust curves, or None.

        The diagnosis refits each mount group's thrust curve, so a per-fan effect is measured
        against its group: when a pattern the library lacks pulls the group's curve, the one fan
        it spares looks stronger than commissioned ("HM3 delivers 17 % more thrust") although it
        is unchanged. A real change since commissioning is there against the curves as
        commissioned too: each finding is refitted with the curves held as the model had them,
        and one whose distance from no effect keeps less than ``min_share`` of the reported one
        is not reported."""
        model = self.model_
        for t in kept:
            model = apply_candidate(model, t.candidate, **t.params)
        labels = {t.candidate.label for t in kept}
        free = np.zeros(len(model.theta), bool)
        for node, sl in param_slices(model):
            if term_label(node) in labels:
                free[sl] = True
        held = fit_model(model, self.train_, free=free, max_nfev=15)
        worst = None
        for t in kept:
            reported = t.params
            as_held = t.candidate.params(_node(held.model, t.candidate.label))
            for name, null in t.candidate.null.items():
                if name not in reported:
                    continue
                ref = np.broadcast_to(np.asarray(null, float), np.shape(reported[name]))
                far = float(np.linalg.norm(np.asarray(reported[name], float) - ref))
                kept_share = float(np.linalg.norm(np.asarray(as_held[name], float) - ref)) / max(far, 1e-12)
                if far > 0 and kept_share < min_share and (worst is None or kept_share < worst[0]):
                    worst = (kept_share, t, name, reported[name], as_held[name])
        if worst is None:
            return None
        _, t, name, value, value_held = worst
        return t, (f'it leans on the refitted thrust curves: against the curves as commissioned its '
                   f'{name} is {values_text(value_held)}, not {values_text(value)} (a pattern the library lacks '
                   f'pulls its group\'s curve and this fan only looks different)')

    def _uncertainty(self, t: Trial, previous: FitResult, fit: FitResult) -> dict:
        """max(Gauss-Newton, delete-one-sweep jackknife) per parameter of the candidate; the
        jackknife refits the candidate's parameters with the rest of the fitted model held."""
        sl = next((sl for node, sl in param_slices(fit.model) if term_label(node) == t.candidate.label), None)
        if sl is None or sl.stop == sl.start:
            return t.std
        try:
            jk = jackknife_std(fit.model, self.train_, np.arange(sl.start, sl.stop), max_nfev=10)
        except FitError:
            return t.std
        jk = _by_parameter(_node(fit.model, t.candidate.label), jk)
        return {name: np.fmax(np.asarray(t.std.get(name, [np.nan] * len(v)), float), v).tolist()
                for name, v in jk.items()}

    # -- results ------------------------------------------------------------------------------
    @property
    def findings_(self) -> list[str]:
        return [t.finding for t in self.steps_]

    @property
    def ranking_(self) -> list[Trial]:
        """The first step's ranked table (every candidate against the refitted model)."""
        return self.rankings_[0] if self.rankings_ else []

    def spread_warning(self) -> str:
        """What is wrong with data whose commands barely vary, and what to record instead
        ('' when they vary enough)."""
        if not self.low_spread_:
            return ''
        return (f'Warning: these sweeps were taken at nearly the same fan commands (command spread '
                f'{100 * self.command_spread_["median"]:.1f} % PWM: the median over the fans of the '
                f'interquartile range of each fan\'s command across the sweeps; the diagnosis wants at '
                f'least {100 * self.min_spread:.0f} %), as in a shaping run that has converged. On such '
                f'data per-fan effects (a fan\'s gain, width, landing point) are poorly identified: a '
                f'held-out sweep at the same commands cannot tell an effect from a patch of the residual '
                f'at this one operating point, so no finding is reported. Record instead 8-12 sweeps of '
                f'~1000 samples at varied commands: each fan spread over its range independently of the '
                f'others, the first and last with the fans off: on the node graph `wind-shaper collect '
                f'--design lhs:12 --out NAME` does that (see docs/workbench.md, "Data").')

    def sync_warning(self) -> str:
        """What to check when the forces and the positions look out of step ('' when not)."""
        return self.sync_.text() if self.sync_ is not None else ''

    def _warnings(self) -> list[str]:
        return [w for w in (self.spread_warning(), self.sync_warning()) if w]

    def summary(self) -> str:
        """The verdict in plain words (with the warnings about data whose commands barely vary
        and about forces and positions out of step)."""
        warnings = self._warnings()
        tail = ''.join(f'\n\n{w}' for w in warnings)
        return self._verdict_text() + tail

    def _verdict_text(self) -> str:
        if self.verdict_ == 'explained':
            return (f'Nothing to report: the model already explains these sweeps (held-out model error '
                    f'{self.baseline_rmse_:.3f} N against measurement noise {self.noise_sd_:.3f} N).')
        if self.verdict_ == 'unexplained':
            if self.low_spread_:
                return (f'No effect can be identified on these sweeps: the held-out model error is '
                        f'{self.baseline_rmse_:.3f} N (noise {self.noise_sd_:.3f} N), but the sweeps\' '
                        f'commands barely vary. See the residual\'s structure below.')
            if self.demoted_:
                more = ' ' + self._demoted_text()
            else:
                best = self.ranking_[0] if self.ranking_ else None
                lowers = (f'lowers it by only {100 * best.gain:.0f} %' if best is not None and best.gain >= 0.005
                          else 'does not lower it')
                more = f' The best candidate, {best.candidate.title}, {lowers}.' if best else ''
            return (f'No candidate explains the residual: the held-out model error stays at '
                    f'{self.baseline_rmse_:.3f} N (noise {self.noise_sd_:.3f} N).{more}'
                    + (' ' + self.undecided_.text() if self.undecided_ is not None else '')
                    + self._outside_text() + ' See the residual\'s structure below.')
        lines = [f'{i + 1}. {t.finding}' for i, t in enumerate(self.steps_)]
        tail = f'\n{self._demoted_text()}' if self.demoted_ else ''
        return (f'Found {len(self.steps_)} effect(s); held-out model error '
                f'{self.baseline_rmse_:.3f} N -> {self.final_rmse_:.3f} N '
                f'({100 * (1 - self.final_rmse_ / self.baseline_rmse_):.0f} % lower):\n' + '\n'.join(lines)
                + tail + ('\n' + self.undecided_.text() if self.undecided_ is not None else '')
                + ('\n\nThe rest is still material.' + self._outside_text()
                   if self.discrepancy_ is not None else ''))

    def _outside_text(self) -> str:
        if self.discrepancy_ is None:
            return ''
        formula = formula_text(self.formula_) if self.formula_ is not None else ''
        return ' ' + (formula + ' ' if formula else '') + outside_text(self.discrepancy_)

    def _demoted_text(self) -> str:
        """'Partly explained by X, but not reported: ...' for effects that failed the check
        across sweeps."""
        parts = [f'{t.candidate.title} (it lowers the held-out error {100 * t.gain:.0f} %), but '
                 f'{"; ".join(t.reasons)}' for t in self.demoted_]
        patch = any(t.check is not None and t.check.spread for t in self.demoted_)
        return ('Partly explained by ' + '; and by '.join(parts)
                + ('. So that is not reported as a finding: the physics is likely something the '
                   'library lacks.' if patch else '. So that is not reported as a finding yet.'))

    def to_json(self) -> dict:
        return {
            'verdict': self.verdict_, 'summary': self.summary(),
            'noise_sd_N': self.noise_sd_,
            'train_sweeps': list(self.train_sweeps_.labels), 'test_sweeps': list(self.test_sweeps_.labels),
            'baseline': {'model': repr(self.baseline_.model), 'train_rmse_N': self.baseline_.rmse,
                         'heldout_model_rmse_N': self.baseline_rmse_, 'heldout_raw_rmse_N': self.baseline_raw_,
                         'bic': self.baseline_.bic},
            'final': {'model': repr(self.final_.model), 'train_rmse_N': self.final_.rmse,
                      'heldout_model_rmse_N': self.final_rmse_, 'heldout_raw_rmse_N': self.final_raw_},
            'findings': [t.to_json() for t in self.steps_],
            'not_reported': [t.to_json() for t in self.demoted_],
            'discrepancy': self.discrepancy_.to_json() if self.discrepancy_ is not None else None,
            'formula': self.formula_.to_json() if self.formula_ is not None else None,
            'undecided': self.undecided_.to_json() if self.undecided_ is not None else None,
            'rankings': [[t.to_json() for t in r] for r in self.rankings_],
            'guard': {'min_gain': self.min_gain, 'min_dbic': self.min_dbic, 'min_z': self.min_z,
                      'material': self.material, 'min_spread': self.min_spread},
            'command_spread': {'median': round(self.command_spread_['median'], 4),
                               'per_fan': {k: round(v, 4) for k, v in self.command_spread_['per_fan'].items()},
                               'too_little': bool(self.low_spread_)},
            'clocks': ({'lag_s': round(self.sync_.lag_s, 4), 'out_of_step': self.sync_.out_of_step,
                        'agree': round(self.sync_.agree, 3), 'mse_drop': round(self.sync_.drop, 4),
                        'per_sweep_s': [round(float(x), 4) for x in self.sync_.per_sweep]}
                       if self.sync_ is not None else None),
            'warnings': self._warnings(),
        }


def _nodes(model):
    from ..model import walk
    return walk(model)


def _node(model, label):
    for n in _nodes(model):
        if term_label(n) == label:
            return n
    return None


def _fans_off_text(t: Trial, min_gain: float) -> str:
    """What a finding judged on the fans-off sweeps (its held-out gain short of ``min_gain``)
    must say."""
    if t.gain_off is None or t.gain >= min_gain:
        return ''
    return (f'. It shows with every fan off: there it lowers the held-out model error '
            f'{100 * t.gain_off:.0f} %, over all held-out sweeps only {100 * t.gain:.0f} % (with the '
            f'fans on, something the library lacks carries most of the residual)')


def _beside_text(t: Trial, model: Term) -> str:
    """What a finding that holds only beside a discrepancy model must say, with the effect as
    estimated jointly with that model (``model``: the final model the finding sits in)."""
    b = t.check.beside if t.check is not None else None
    if b is None or not b.passed:
        return ''
    sl = next(sl for node, sl in param_slices(model) if term_label(node) == t.candidate.label)
    theta = np.array(model.theta, float)
    theta[sl] = b.mean
    node = _node(model.with_theta(theta), t.candidate.label)
    joint = t.candidate.describe(node, _by_parameter(node, b.mean_std))
    return (f'. It holds across sweeps only with a discrepancy model beside it (something the '
            f'library lacks perturbs it sweep by sweep); estimated jointly with that model: {joint}')

