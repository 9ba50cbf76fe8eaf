"""The improved update rule (``AdaptiveUpdate``).

Units: commands U are fractions 0..1 of full PWM, one per fan; forces [N] at the key points
[m, tunnel frame]; errors are mean squared differences over the key points [N^2].

What the paper's Algorithm 1 does, and what ``AdaptiveUpdate`` does instead:

* **Bounded step, not clipping.** The step solves a least-squares problem with the PWM limits
  (and a trust region) as box constraints (``box_qp``, a projected-Newton QP; L-BFGS-B for
  large walls), so a fan that hits its limit leaves the others to make up for it instead of
  being cut off after the fact.
* **The prior, corrected by the data.** The field predicted for new commands U is anchored at
  the measured field of the best iteration so far, F_b, and moves as the prior says:

      F(U) ~ F_b + M(U) - M(U_b) + D (U - U_b)

  M is the prior after a per-fan correction fitted to every field map of the run (each fan's
  gain, the landing point of its jet and its width, as a linear correction of the prior's
  footprint: ``ShapeFit``); D is a multi-secant correction (``SecantCorrection``) from the
  field changes M did not predict. M keeps the prior's nonlinear PWM-to-force curve, so large
  first steps (a fan from 50 % to 0 %) land where the prior says, not where its tangent says.
* **Step size from the data.** A trust region (infinity norm, in PWM) grows when the measured
  error fell as predicted and shrinks when it did not; a step that made the measured error
  clearly worse is not built upon (the next step starts again from the best iteration).
* **Uncertainty.** Key points where the GP is unsure weigh less (optional, ``weighting``).
* **Stopping.** ``StoppingRule`` says when the predicted improvement of the next step is below
  what the noise of the field estimate lets a sweep resolve.

The rule keeps no state between calls: everything it learns is recomputed from
``UpdateInput.history`` (what ``ShapingLoop`` passes), so a node that builds a fresh rule per
iteration loses nothing. Without a history it still takes a bounded, prior-model step; without
``model``/``key_points``/``target`` it falls back to the Jacobian it is given (linear prior).

Its parts live beside it: ``basis`` (``FanBasis``, the prior fan by fan), ``shape_fit``
(``ShapeFit``), ``secant`` (``SecantCorrection``), ``qp`` (``box_qp`` and the bounded steps) and
``stopping`` (``StoppingRule``).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..core.errors import ConfigError
from .basis import FanBasis
from .chain import Contradiction, chain_start, contradiction
from .qp import _bounded_lsq, _thrust_space_qp, _thrust_space_step
from .secant import SecantCorrection
from .shape_fit import BASES, ShapeFit, _fit_gains_sparse
from .stopping import StoppingRule
from .update import CommandBounds, UpdateInput, UpdateStep

#: The prior's factorisation (``FanBasis``) for the current model and key points, one entry at a
#: time (``AdaptiveUpdate._basis``).
_BASIS_CACHE: dict[Any, Any] = {}

#: Fits to the commissioning's maps alone (the shared curve's test, the anchor of later fits),
#: which every step of a run would otherwise redo on the same maps (``_commissioning_fit``).
_COMMISSIONING_FITS: dict[Any, Any] = {}


def _commissioning_fit(fit: ShapeFit, basis: FanBasis, maps, on) -> np.ndarray:
    """``fit.fit(basis, maps, on)``, remembered for the run: the same settings, prior, enabled
    fans and maps (U, F, w, by a digest of their bytes) give the same theta."""
    digest = hashlib.blake2b(digest_size=16)
    for U, F, w in maps:
        for part in (U, F, w):
            digest.update(np.ascontiguousarray(part, dtype=float).tobytes())
    key = (fit, id(basis), np.asarray(on, bool).tobytes(), digest.digest())
    hit = _COMMISSIONING_FITS.get(key)
    if hit is None or hit[0] is not basis:
        if len(_COMMISSIONING_FITS) >= 8:
            _COMMISSIONING_FITS.clear()
        hit = _COMMISSIONING_FITS[key] = (basis, fit.fit(basis, maps, on))
    return hit[1].copy()


#: ``first_step_from_level``: a fan is low at the warm start below this share of the low level
#: sweep's command (3/4: 0.15 PWM on the default range, where the low level runs 0.195).
LOW_SHARE = 0.75

#: Settings checked against a range: name -> (low, high, what the number is).
_RANGES = {
    'gain_common_sd': (0, 1, 'a share of the gain'),
    'load_sd': (0, 5, 'gain change per unit of the mean command'),
    'commissioning_weight': (0, 10, "against one of the run's maps"),
    'commissioning_reach': (0, 1, 'a PWM fraction'),
    'pool_within': (0, 1, 'a PWM fraction'),
    'curve_sd': (0, 1, "a share of the fan's thrust"),
    'shared_margin': (0, 1000, 'a log Bayes factor'),
    'shared_curve_sd': (0, 1, "a share of every fan's thrust"),
    'curve_risk': (0, 10, "times the curves' posterior variance"),
    'ridge_share': (0, 10, "a share of the base's predicted error"),
    'spread_sd': (0, 1, "a share of each fan's force"),
    'tilt_sd': (0, 5, 'N per 0.1 m across the section'),
    'off_margin': (0, 100, "times the estimate's noise"),
}


@dataclass(frozen=True)
class AdaptiveUpdate:
    """Trust-region steps on a data-corrected prior (see the module docstring).

    bounds: command limits; step_fraction: fraction of the computed step taken (1 = all of it);
    radius: first trust radius [PWM fraction, largest change of any fan]; radius_min,
    radius_max: its limits; correction: 'shape' (per-fan gain, landing point and width fitted
    to every map), 'gain' (per-fan gain only) or 'none' (the prior as it is); fit_from: maps
    needed before the correction is fitted; swirl: also fit the field's turn with the CW/CCW
    thrust balance (``ShapeFit``; small rigs only); secant: correct the Jacobian with the measured
    changes the corrected prior did not predict; secant_memory: pairs used; secant_min_step:
    smallest step [fraction] a pair may come from; secant_scale: prior size of the secant
    correction relative to the prior Jacobian's RMS column (sets its ridge); noise_std [N]:
    noise floor of a field estimate at a key point; memory: maps (besides the best one) the
    fit and the secant use, the most recent first (12: every map of a default-length run; a
    shorter window dropped the first maps, whose different loads alone showed the load slope,
    and the slope fell back to its prior mid-run); weighting: weigh key points by
    1 / (1 + (std / noise_std)^2); damping: Marquardt damping of every step (a fan's move
    costs damping x its column's squared norm; keeps nearly collinear fans of a dense wall
    from trading large opposite moves); idle_below [fraction]: a command below this is sent as
    u_min (an ESC does not turn a propeller that slowly; with u_min = 0 the feasible set is
    {0} and [idle_below, u_max]); inner_iterations: Gauss-Newton passes on the nonlinear model
    per step; stop_factor, stop_patience: the ``StoppingRule``; fit_points: how many
    independent key points one map counts as in the per-fan fit (a map's GP estimates are
    strongly correlated; None: every key point counts); relearn: learn again from the newest
    map when it contradicts the earlier ones (``chain``); pool_within [PWM fraction]: the maps
    whose commands all lie within this of the base's are averaged into the base's residual (see
    ``_pooled_residual``); 0 uses the base's map alone; gain_common_sd [-]: the sd of a gain
    deviation all fans share in the per-fan fit (``ShapeFit``; 0: none), so a fan idle in every
    map so far moves with the others' correction; load_sd [1 per unit command]: the prior sd of
    a shared slope of every fan's gain with the mean command (``ShapeFit``; never above 0; 0:
    none), for a starved inlet or a sagging supply; ``info['load_slope']`` is the one used;
    commissioning_weight [-]: the weight, against one of the run's maps, of each commissioning
    map (``UpdateInput.prior_maps``) in the first update's fit (0: not used; dense priors only);
    commissioning_reach [PWM fraction]: later updates fit them too, each weighed by
    exp(-(d / reach)^2) with d the largest difference of its commands from the base's (0: the
    first update only); ``info['commissioning_maps']`` says how many went in and
    ``info['commissioning_weight']`` their summed weight; commissioning_landing: a later step
    longer than the reach is solved again with d the nearer of the map's difference from the
    base's commands and from where that step lands (``info['landing']``: those commands), so
    the fit that sends a far step has the commissioning's maps near its end in it (False: the
    base only); commissioning_anchor: later updates
    start their fit from what the commissioning's maps alone teach of each fan (the per-fan
    correction fitted to them, as the prior's mean; its sd as before), so a fan the run has not
    yet run, on which its maps say nothing, keeps what the commissioning showed instead of
    falling back to the prior's gain once the far maps have faded (off after a first sweep that
    contradicted the prior, or once the run has relearned); curve_sd [-]: the prior sd of the
    bumps by which each fan's gain varies with its own command in the per-fan fit
    (``ShapeFit.curve_sd``: a stall dip or a dead band in one fan's curve; 0: none; dense priors
    only, a large wall's fit keeps per-fan gains), used only while the commissioning's maps are
    in the fit (``_curve_learnable``); ``info['curve']`` says whether it was; curve_risk [-]: while
    the curves are bent, each step minimises the predicted error plus this times the variance
    the fit's posterior leaves in each fan's curve over the fan's move from the base (fan by
    fan), so that a move across a part of a curve no map has pinned down (a stall dip seen by
    one sweep) pays for what it may turn out to be; 0: the predicted error alone; ridge_share
    [-]: a step along which the corrected prior predicts fields worse than the base's by more
    than this share of the base's predicted error (and by more than the step's end gains), on
    the way straight in the fans' thrusts from the base (where the prior's own part is convex, so
    the rise is what the fit bent in: a stall dip, the load slope), is replaced by Gauss-Newton
    passes from the base cut back before any such rise: the far side of a fitted dip is the
    fit's extrapolation from far maps, and a step that crossed one on a stall-dip tunnel more
    than doubled the error's distance to the best; ``info['ridge']`` says where the way rose
    (None: no such ridge); 0: off; level_map: the
    commissioning's maps with every enabled fan at one command (the two level sweeps of
    `collect --design lhs:N+level`, at the middle of the range and low in it) are among the
    run's maps in every update while the tunnel is the one commissioned: fitted at full weight,
    however far from the base, and in the secant. The run's own maps sit near an optimum that
    keeps some fans low, where their thrust, and so what the maps show of them, is small; a
    level map shows every fan running at one load, where the fans' curves have no ends to bend
    the fit (the designed sweeps' far maps fade instead), and the low one shows them where such
    an optimum keeps many of them. ``info['level_map']`` says whether they were used and
    ``info['level_maps']`` how many;
    spread_sd [-], tilt_sd [N per 0.1 m]: the prior sds of the per-fan fit's share of every
    jet's force spread evenly over the key points (never below 0) and of a plane across the
    section (``ShapeFit``; 0: none; dense priors only): a screen's or mixing's even share grows
    with the total thrust, a warm wall's or a draft's plane stays whatever the fans do; left
    out, the fit bends the gains and the load slope to hold them, and the steps mispredict how
    the field's level follows the fans. ``info['spread_share']`` is the share used;
    off_margin [x the estimate's noise]: a step that would switch a running fan off (its command
    below ``idle_below``) takes it half way down instead, still running, unless switching it off
    is predicted to gain more than this times the noise of one sweep's error (the stopping
    rule's) over that step: the run's maps seldom show a fan off, and the prior's curve is least
    known near the bottom of the range (a dead band, an idle disc's backflow, an ESC's crosstalk
    left out of the fit), while a fan that should be off is off two or three steps later.
    ``info['held_on']`` says how many fans a step took half way down; 0: off;
    first_step_from_level [fans]: when the warm start leaves at least this many enabled fans
    below ``LOW_SHARE`` of the low level sweep's command, the first update steps from the level
    map the commissioning measured best instead of from the first sweep (which stays among the
    maps it fits): the prior's optimum is then least known where it keeps those fans, and a step
    from every fan running interpolates between maps that show them. Later updates step from
    the run's best map as always; ``info['from_level']`` says whether it did; 0: off;
    first_step_from_top [fans]: the same first step from the best level map when the warm start
    holds at least this many enabled fans at ``bounds.u_max``: the prior wants more of them
    than they give, so it underrates them, and at the top of the range it extrapolates their
    curves as it does at the bottom (a central jet that flaps when it outruns the ring loses
    force at the centre as its fan speeds up); 0: off.
    """

    bounds: CommandBounds = CommandBounds()
    step_fraction: float = 1.0
    radius: float = 0.35
    radius_min: float = 0.01
    radius_max: float = 0.65
    correction: str = 'shape'
    fit_from: int = 1
    secant: bool = True
    secant_memory: int = 6
    secant_min_step: float = 0.02
    secant_scale: float = 0.3
    noise_std: float = 0.1
    weighting: bool = False
    damping: float = 0.05
    idle_below: float = 0.02
    locality: float | None = None
    memory: int = 12
    swirl: bool = True
    inner_iterations: int = 5
    stop_factor: float = 0.5
    stop_patience: int = 1
    fit_points: float | None = 20.0
    relearn: bool = True
    pool_within: float = 0.05
    gain_common_sd: float = 0.0
    load_sd: float = 0.0
    commissioning_weight: float = 1.0
    commissioning_reach: float = 0.15
    commissioning_anchor: bool = True
    curve_sd: float = 0.0
    shared_curve_sd: float = 0.0
    shared_margin: float = 10.0
    curve_risk: float = 0.0
    ridge_share: float = 0.0
    level_map: bool = True
    spread_sd: float = 0.0
    tilt_sd: float = 0.0
    off_margin: float = 0.0
    commissioning_landing: bool = True
    first_step_from_level: int = 0
    first_step_from_top: int = 0

    #: the loop may skip the (dense) prior Jacobian: this rule reads the model itself.
    needs_jacobian = False
    method = 'adaptive'

    def __post_init__(self):
        if not 0 < self.step_fraction <= 1:
            raise ConfigError(f'adaptive update step_fraction must be in (0, 1], got {self.step_fraction}')
        if not 0 < self.radius_min <= self.radius <= self.radius_max:
            raise ConfigError(f'trust radii need 0 < radius_min <= radius <= radius_max; got '
                              f'{self.radius_min}, {self.radius}, {self.radius_max}')
        if self.correction not in ('shape', 'gain', 'none'):
            raise ConfigError(f'correction must be shape, gain or none; got {self.correction!r}')
        if not (self.noise_std > 0 and self.secant_scale > 0 and self.inner_iterations >= 1
                and self.fit_from >= 1):
            raise ConfigError('noise_std and secant_scale must be > 0, inner_iterations and '
                              'fit_from >= 1')
        for name in ('first_step_from_level', 'first_step_from_top'):
            fans = getattr(self, name)
            if not (isinstance(fans, (int, np.integer)) and not isinstance(fans, bool) and fans >= 0):
                raise ConfigError(f'{name} must be a whole number of fans >= 0 (0: off), got {fans!r}')
        for name, (low, high, what) in _RANGES.items():
            value = getattr(self, name)
            if not low <= value <= high:
                raise ConfigError(f'{name} must be in [{low}, {high}] ({what}), got {value}')

    @property
    def stopping(self) -> StoppingRule:
        return StoppingRule(factor=self.stop_factor, floor=0.5 * self.noise_std,
                            patience=self.stop_patience)

    # -- the prior ---------------------------------------------------------------------------
    def _basis(self, inp: UpdateInput):
        """The separable factorisation of the prior, cached per (model, key points)."""
        if inp.model is None or inp.key_points is None or inp.target is None or self.correction == 'none':
            return None
        cache = _BASIS_CACHE
        key = (id(inp.model), inp.key_points.shape, float(np.sum(inp.key_points)))
        hit = cache.get(key)
        if hit is not None and hit[0] is inp.model:
            return hit[1]
        try:
            basis = FanBasis.from_term(inp.model, inp.key_points)
        except ConfigError:
            basis = None
        cache.clear()  # one run at a time; a new model or key points replaces the old entry
        cache[key] = (inp.model, basis)
        return basis

    def _commissioning_weights(self, inp: UpdateInput, history, fit_from: int, relearn, U_b,
                               landing=None) -> list:
        """The weight, against one of the run's maps, of each commissioning map in this update's
        fit: ``commissioning_weight`` each in the first update; in later ones that times
        exp(-(d / commissioning_reach)^2), d [PWM fraction] the largest difference of the map's
        commands from the base's, or from ``landing`` [PWM fraction] where that is nearer
        (``commissioning_landing``); 0 when ``commissioning_reach`` is 0. None at all without a
        target, after the first sweep contradicted the prior, or once the run has relearned (the
        tunnel is no longer the one commissioned)."""
        maps = inp.prior_maps
        if self.commissioning_weight <= 0 or inp.target is None or not maps:
            return [0.0] * len(maps)
        if not history:
            return [self.commissioning_weight if inp.k == 0 else 0.0] * len(maps)
        if self.commissioning_reach <= 0 or not self._still_commissioned(history, fit_from, relearn):
            return [0.0] * len(maps)
        far = [float(np.max(np.abs(np.asarray(p.U, float) - U_b))) for p in maps]
        if landing is not None:
            far = [min(d, float(np.max(np.abs(np.asarray(p.U, float) - landing)))) for d, p in zip(far, maps)]
        return [self.commissioning_weight * float(np.exp(-(d / self.commissioning_reach) ** 2)) for d in far]

    @staticmethod
    def _still_commissioned(history, fit_from: int, relearn) -> bool:
        """Whether the tunnel is still the one the commissioning's maps describe: its first
        sweep did not contradict the prior and the run has not relearned since."""
        first = dict(history[0].info).get('warm_start') or {} if history else {}
        return relearn is None and fit_from == 0 and not (first.get('check') or {}).get('mismatch')

    def _curve_learnable(self, inp: UpdateInput, history, fit_from: int, relearn) -> bool:
        """Whether the fit may bend each fan's curve (``curve_sd``): only while the commissioning's
        maps, which run every fan across its command range, are in it. The run's own maps sit
        close together, where a bend in one fan's curve and its gain look alike: fitted on them
        alone (no commissioning maps, after a restart, once the run has relearned) the bumps
        take up the model's misfit as false dips and hold the steps in a wrong basin."""
        if self.curve_sd <= 0 or not inp.prior_maps or self.commissioning_weight <= 0:
            return False
        return not history or self._still_commissioned(history, fit_from, relearn)

    def _fit_weight(self, past, weight: float) -> np.ndarray:
        """A commissioning map's weight per key point in the fit: ``weight`` (against one of the
        run's maps) times noise_std^2 / (noise_std^2 + its std^2) (its std 0 when not kept)."""
        n2 = self.noise_std ** 2
        std2 = 0.0 if past.std is None else np.asarray(past.std, float) ** 2
        return np.broadcast_to(weight * n2 / (n2 + std2), np.shape(past.mean)).astype(float)

    def step(self, inp: UpdateInput) -> UpdateStep:
        return self._step(inp, relearn=None)

    def _step(self, inp: UpdateInput, relearn: Contradiction | None, landing=None) -> UpdateStep:
        """One step; ``relearn``: the newest map contradicted the earlier ones, so this step
        uses the newest map alone (``chain``); ``landing`` [PWM fraction]: where a first solve
        sent a step longer than ``commissioning_reach`` (``commissioning_landing``)."""
        on = np.asarray(inp.enabled, dtype=bool)
        U_k = self.bounds.project(inp.U, on)
        delta = np.asarray(inp.delta, dtype=float)
        N = len(delta)
        target = None if inp.target is None else np.asarray(inp.target, dtype=float)
        ref = target if target is not None else np.zeros(N)
        # every map of the run: (U, F - F_des, std). Without the target the earlier maps cannot
        # be related to this one (only F_des - F_k is known), so the history is not used.
        history = inp.history if target is not None else ()

        def as_map(p, info):
            return (np.asarray(p.U, float), np.asarray(p.mean, float) - ref,
                    None if p.std is None else np.asarray(p.std, float), info)
        # The commissioning's level maps (every enabled fan at one command) join the run's maps,
        # first (``level_map``); a base to step from only for the first update (``first_step_from_level``).
        use_level = self.level_map and target is not None and self.commissioning_weight > 0
        level = [p for p in inp.prior_maps if is_level(p.U, on)] if use_level else []
        n_level = len(level)
        maps = [as_map(p, {'commissioning': True}) for p in level] + [as_map(p, dict(p.info)) for p in history]
        maps.append((U_k, -delta, None if inp.std is None else np.asarray(inp.std, float), {}))
        noise2 = [self.noise_std ** 2 + (0.0 if s is None else s ** 2) for _, _, s, _ in maps]
        weights = [np.ones(N) if not self.weighting else 1.0 / (1.0 + (0.0 if s is None else s ** 2) / self.noise_std ** 2)
                   for _, _, s, _ in maps]
        errors = np.array([float(np.mean(r ** 2)) for _, r, _, _ in maps])
        stop_rule = self.stopping
        err_noise = stop_rule.noise(inp.std)

        # -- the maps the steps build on and the fit uses (``chain``: restarts, relearning) ------
        base_from, fit_from = chain_start([m[3] for m in maps])
        base_from = max(base_from, n_level)
        if relearn is not None:
            base_from = fit_from = len(maps) - 1
        if n_level and history and not self._still_commissioned(history, fit_from, relearn):
            fit_from = max(fit_from, n_level)   # not the tunnel commissioned: its map goes too
        restarted = relearn is not None or (bool(history) and base_from == len(maps) - 1
                                             and 'restart_next' in dict(history[-1].info))

        # -- the base: the best map so far (ties go to the latest) ----------------------------
        b = int(len(maps) - 1 - np.argmin(errors[base_from:][::-1]))
        if errors[-1] <= errors[b] + 0.5 * err_noise:
            b = len(maps) - 1
        from_level = False
        if ((self.first_step_from_level or self.first_step_from_top) and inp.k == 0 and not history
                and n_level and relearn is None):
            # The prior's optimum leaves fans low, or holds one at the top of its range, where
            # their curves are least known (a dead band, a stall, a starved inlet; a fan the
            # prior underrates, whose jet may even lose strength there) and the commissioning's
            # designed maps seldom went: a first step from there extrapolates. From the level
            # map the sweeps measured best, every fan running, it interpolates between maps
            # that show them.
            low_level = min(float(np.max(maps[i][0])) for i in range(n_level))
            low = int(np.sum(on & (U_k < LOW_SHARE * low_level)))
            top = int(np.sum(on & (U_k >= self.bounds.u_max - 1e-9)))
            if ((self.first_step_from_level and low >= self.first_step_from_level)
                    or (self.first_step_from_top and top >= self.first_step_from_top)):
                b, from_level = int(np.argmin(errors[:n_level])), True
        U_b, r_b = maps[b][0], maps[b][1]
        if self.locality:
            near = [np.exp(-(np.max(np.abs(U - U_b)) / self.locality) ** 2) for U, _, _, _ in maps]
        else:
            near = [1.0] * len(maps)
        # the fit and the secant use the most recent `memory` maps and the base (a bound on the
        # cost of long runs; a default-length run keeps all its maps)
        window = sorted(set(range(max(fit_from, len(maps) - self.memory), len(maps))) | {b}
                        | set(range(fit_from, n_level)))
        # The first update also fits the commissioning's maps (``UpdateInput.prior_maps``): the
        # run has one map, at the prior's optimum, and a step from a fit on it alone lands
        # where that map cannot tell; maps across the command range can. Later updates fit
        # only those near the base (``commissioning_reach``): far maps weigh heavily on a fit's
        # slopes and would hold the steps near the optimum to the prior's form.
        kept = [(p, w) for p, w in zip(inp.prior_maps, self._commissioning_weights(inp, history, fit_from, relearn, U_b, landing))
                if w > 1e-3 * self.commissioning_weight and all(p is not q for q in level)]   # fainter ones: no change, cost time
        broad = [(np.asarray(p.U, float), np.asarray(p.mean, float), self._fit_weight(p, w)) for p, w in kept]
        # -- the prior model M(U) and its Jacobian, corrected by the maps ----------------------
        basis = self._basis(inp)
        fitted = len(maps) >= self.fit_from
        slope = 0.0   # the shared load slope of the gains (ShapeFit.load_sd), dense priors only
        spread = 0.0   # the share of the jets spread over the section (ShapeFit.spread_sd), the same
        curved = False   # whether the fit bent the fans' curves (``_curve_learnable``)
        shared_curve = False   # whether it bent the curve they share (``shared_curve_sd``)
        curve_cov = None   # (n, K, K): the posterior covariance of each fan's curve weights
        if basis is not None and basis.sparse:
            # A large wall: per-fan gains only, on the Gram matrix of the footprints (cached per
            # run); no secant and no swirl term; the step is a bounded QP in thrust space.
            gains = np.ones(basis.n_fans)
            if fitted and self.correction != 'none':
                gains = _fit_gains_sparse(basis, [(maps[i][0], maps[i][1] + ref,
                                                   float(np.mean(near[i] * weights[i] / noise2[i])) * self.noise_std ** 2)
                                                  for i in window],
                                          on, self.noise_std, ShapeFit().gain_sd, ShapeFit().offset_sd)
            Smat = (basis.shape @ sp.diags(gains)).tocsc()

            def model(U):
                return np.asarray(Smat @ basis.thrust(U)[0]).ravel(), None
            mode = 'gain' if fitted else 'prior'
        elif basis is not None:
            fit = ShapeFit(bases=BASES if self.correction == 'shape' else ('gain',),
                           swirl=self.swirl and not basis.sparse, noise_std=self.noise_std,
                           gain_common_sd=self.gain_common_sd, load_sd=self.load_sd,
                           spread_sd=self.spread_sd, tilt_sd=self.tilt_sd,
                           curve_sd=self.curve_sd if self._curve_learnable(inp, history, fit_from, relearn) else 0.0,
                           shared_curve_sd=self.shared_curve_sd, shared_margin=self.shared_margin)
            if fitted:
                share = 1.0 if self.fit_points is None else min(1.0, self.fit_points / N)
                commissioned = [(np.asarray(p.U, float), np.asarray(p.mean, float),
                                 share * self._fit_weight(p, self.commissioning_weight)) for p in inp.prior_maps]
                if fit.shared_curve_sd > 0 and fit.curved:
                    # a curve every fan shares only where the commissioning's maps, which run every
                    # fan across its range, show one (``ShapeFit.shared_margin``); not to explain
                    # what the run's first maps, bunched at low commands, miss for other reasons
                    shown = fit.shared_curve_used(_commissioning_fit(fit, basis, commissioned, on))
                    fit = replace(fit, shared_curve_sd=self.shared_curve_sd if shown else 0.0, shared_margin=-np.inf)
                if (self.commissioning_anchor and history and inp.prior_maps and self.commissioning_weight > 0
                        and self._still_commissioned(history, fit_from, relearn)):
                    # what the commissioning taught of each fan is the prior of the later fits:
                    # a fan the run has not run yet keeps it instead of falling back to the prior's
                    fit = replace(fit, prior_mean=tuple(_commissioning_fit(fit, basis, commissioned, on)))
                abs_maps = [(maps[i][0], maps[i][1] + ref, share * near[i] * weights[i] / noise2[i] * self.noise_std ** 2)
                            for i in window]
                abs_maps += [(U, F, share * w) for U, F, w in broad]
                if self.curve_risk > 0 and fit.curved:
                    theta, cov = fit.fit_posterior(basis, abs_maps, on)
                    curve_cov = fit.curve_cov(cov, basis.n_fans)
                else:
                    theta = fit.fit(basis, abs_maps, on)
            else:
                theta = fit.prior(basis.n_fans)[0]
            Smat = fit.shape_matrix(basis, theta)
            g_swirl = fit.swirl_gain(theta)
            slope = fit.load_slope(theta)
            spread = fit.spread_share(theta)
            curved = fit.curved
            shared_curve = fit.shared_curve_used(theta)
            dload = np.where(on, 1.0 / max(1, int(on.sum())), 0.0)   # dL/dU

            def model(U):
                a, da = basis.thrust(U)
                val = np.asarray(Smat @ a).ravel()
                jac = Smat @ sp.diags(da) if sp.issparse(Smat) else Smat * da
                if g_swirl:
                    w, dw = fit.balance(basis, a, da)
                    ra = basis.rot @ a
                    val = val + g_swirl * w * ra
                    jac = jac + g_swirl * (w * (basis.rot * da) + np.outer(ra, dw))
                if slope:
                    load, sa = fit.load(U, on), basis.shape @ a
                    val = val + slope * load * sa
                    jac = jac + slope * (load * (basis.shape * da) + np.outer(sa, dload))
                if fit.curved:
                    h, dh = fit.curve(theta, U, basis.n_fans)
                    val = val + basis.shape @ (a * h)
                    jac = jac + basis.shape * (da * h + a * dh)
                return val, jac
            mode = 'shape' if fitted else 'prior'
        elif inp.model is not None and inp.key_points is not None:
            def model(U):
                return inp.model.value_and_jacobian(U, inp.key_points)
            mode = 'prior'
        else:
            if inp.jacobian is None:
                raise ConfigError('the adaptive update needs the prior: pass model and key_points, '
                                  'or the Jacobian at U')
            J_k = np.asarray(inp.jacobian, dtype=float)

            def model(U):
                return J_k @ (np.asarray(U) - U_k), J_k
            mode = 'linear'

        M_vals = {i: model(maps[i][0])[0] for i in window}
        M_b, J_b = model(U_b)
        r_b, pooled = _pooled_residual(maps, window, b, near, noise2, M_vals, M_b, self.pool_within)

        # -- does the newest map contradict what the earlier ones taught? -----------------------
        if relearn is None and self.relearn:
            verdict = contradiction(maps, max(fit_from, n_level), model, 0.5 * self.noise_std)
            if verdict is not None and verdict.contradicts:
                return self._step(inp, relearn=verdict, landing=landing)

        # -- trust radius from the last step's prediction ---------------------------------------
        radius, rho, accepted = self.radius, None, True
        if not history and inp.k > 0:
            # Called without the run's history (e.g. by a node that keeps none): the rule cannot
            # see whether its steps work, so the radius shrinks like the paper's schedule.
            radius = max(self.radius_min, self.radius / (inp.k + 1))
        if history and not restarted:
            last = dict(history[-1].info)
            radius = float(last.get('radius', self.radius))
            pred, base_err = last.get('predicted_error'), last.get('base_error')
            moved = float(np.max(np.abs(U_k - np.asarray(history[-1].U)))) if 'base_k' not in last else \
                float(np.max(np.abs(U_k - maps[int(last['base_k'])][0])))
            if pred is not None and base_err is not None:
                predicted = base_err - pred
                actual = base_err - errors[-1]
                accepted = actual > -err_noise
                if predicted > err_noise:
                    rho = actual / predicted
                    if rho < 0.25:
                        radius = max(self.radius_min, 0.5 * moved)
                    elif rho > 0.75 and moved >= 0.9 * radius:
                        radius = min(self.radius_max, 2.0 * radius)
                elif actual < -2.0 * err_noise:
                    radius = max(self.radius_min, 0.5 * moved)

        # -- secant correction of what M did not predict --------------------------------------
        secant = None
        if self.secant and len(maps) > 1 and J_b is not None:
            steps, misses = [], []
            e_b = r_b - M_vals[b]
            for i in window:
                if i != b:
                    steps.append(maps[i][0] - U_b)
                    misses.append((maps[i][1] - M_vals[i]) - e_b)
            order = np.argsort([np.max(np.abs(s)) for s in steps])  # largest steps kept last
            steps = [steps[i] for i in order]
            misses = [misses[i] for i in order]
            cols = np.asarray(np.sqrt((J_b.power(2) if sp.issparse(J_b) else J_b ** 2).sum(axis=0))).ravel()
            col_rms = float(np.sqrt(np.mean(cols[on] ** 2) / N)) if on.any() else 1.0
            tau = self.secant_scale * max(col_rms, 1e-9)
            ridge = 2.0 * float(np.mean(noise2[-1])) / tau ** 2
            secant = SecantCorrection(ridge=ridge, min_step=self.secant_min_step,
                                      memory=self.secant_memory).fit(steps, misses)
            if secant.n_pairs_ == 0:
                secant = None

        # -- the bounded step ----------------------------------------------------------------
        lo = np.where(on, np.maximum(self.bounds.u_min, U_b - radius), 0.0)
        hi = np.where(on, np.minimum(self.bounds.u_max, U_b + radius), 0.0)
        w_b = weights[b]

        def predict(U):
            v, J = model(U)
            pred = r_b + (v - M_b)
            if secant is not None:
                pred = pred + secant.matvec(U - U_b)
            return pred, J

        risk = None if curve_cov is None else _CurveRisk(basis, curve_cov, U_b, self.curve_risk * w_b)

        def objective(pred, U):
            f = float(np.mean(w_b * pred ** 2))
            return f if risk is None else f + risk(U)[0]

        def refine(U_c, pred_c, J_c, f_c, lo, hi):
            """Gauss-Newton passes on the model from U_c within [lo, hi], each with a
            backtracking line search."""
            for _ in range(self.inner_iterations if idx.size and J_b is not None else 0):
                separable = None
                if risk is not None:   # in the solver's units: summed over the key points
                    _, h_fan, g_fan = risk(U_c)
                    separable = (N * h_fan[idx], N * g_fan[idx])
                du = _bounded_lsq(J_c, secant, pred_c, np.sqrt(w_b), idx, lo[idx] - U_c[idx], hi[idx] - U_c[idx],
                                  self.damping, separable)
                t, improved = 1.0, False
                while t > 1e-3:
                    U_t = U_c.copy()
                    U_t[idx] = np.clip(U_c[idx] + t * du, lo[idx], hi[idx])
                    pred_t, J_t = predict(U_t)
                    f_t = objective(pred_t, U_t)
                    if f_t < f_c:
                        improved = True
                        break
                    t *= 0.5
                if not improved:
                    break
                done = np.max(np.abs(U_t - U_c)) < 1e-5
                U_c, pred_c, J_c, f_c = U_t, pred_t, J_t, f_t
                if done:
                    break
            return U_c, pred_c, J_c, f_c

        idx = np.flatnonzero(on)

        def solve(lo, hi):
            """The step within [lo, hi]: (U_next as sent, its predicted residual, the ridge)."""
            U_c = U_b.copy()
            pred_c, J_c = predict(U_c)
            f_c = objective(pred_c, U_c)
            from_base = (U_c, pred_c, J_c, f_c, lo, hi)
            if J_b is None:  # large wall: the bounded QP in thrust space is the whole step
                if idx.size:
                    U_c = _thrust_space_qp(basis, gains, r_b, U_b, lo, hi, idx, self.damping)
                    pred_c, _ = predict(U_c)
            elif basis is not None and idx.size and basis.monotone:
                # The corrected prior is linear in the per-fan thrusts a_j: solve the bounded
                # problem there exactly (a fan idling at PWM 0, where da/dU = 0, can come back),
                # then refine in PWM space, where the secant term lives.
                # the load slope makes the model bilinear in the thrusts: held at the base's load here
                S_step = Smat if not slope else Smat + slope * ShapeFit.load(U_b, on) * basis.shape
                U_t = _thrust_space_step(basis, S_step, r_b, np.sqrt(w_b), U_b, lo, hi, idx, self.damping)
                pred_t, J_t = predict(U_t)
                f_t = objective(pred_t, U_t)
                if f_t < f_c:
                    U_c, pred_c, J_c, f_c = U_t, pred_t, J_t, f_t
                    # the convex thrust-space problem decides which limits are active: fans it put on
                    # a limit stay there (at PWM 0 the model's slope is 0, so the refinement below
                    # could only wander off it on noise)
                    pinned = (U_t <= lo + 1e-12) | (U_t >= hi - 1e-12)
                    lo, hi = np.where(pinned, U_t, lo), np.where(pinned, U_t, hi)
            U_c, pred_c, J_c, f_c = refine(U_c, pred_c, J_c, f_c, lo, hi)
            ridge = None
            if self.ridge_share > 0 and J_b is not None and idx.size:
                # A step the model itself says passes through much worse fields (a stall dip it
                # fitted between the base and the step's end) bets on its extrapolation to another
                # basin, which only faded commissioning maps describe: the step stays in the base's
                # basin instead (Gauss-Newton from the base, cut back before any ridge left)
                way = basis if basis is not None and basis.monotone else None

                def predicted(U):
                    return objective(predict(U)[0], U)
                ridge = _ridge(predicted, U_b, U_c, self.ridge_share, err_noise, way)
                if ridge is not None:
                    U_c, pred_c, J_c, f_c = refine(*from_base)
                    U_c = _before_ridge(predicted, U_b, U_c, self.ridge_share, err_noise, way)
                    pred_c, J_c = predict(U_c)
                    f_c = objective(pred_c, U_c)
            U_next = self.bounds.project(U_b + self.step_fraction * (U_c - U_b), on)
            if self.idle_below > self.bounds.u_min:
                # no ESC turns a propeller at a few percent PWM: such a command is sent as u_min
                U_next = np.where(on & (U_next < self.idle_below), self.bounds.u_min, U_next)
            if self.step_fraction < 1 or not np.array_equal(U_next, U_c):
                pred_c, _ = predict(U_next)
            return U_next, pred_c, ridge

        U_next, pred_c, ridge = solve(lo, hi)
        if (self.commissioning_landing and landing is None and mode == 'shape' and history
                and self.commissioning_reach > 0 and self._still_commissioned(history, fit_from, relearn)
                and float(np.max(np.abs(U_next - U_b))) > self.commissioning_reach):
            # A step beyond the reach lands where the fit had only faded maps: solve again with
            # the commissioning's maps near that landing weighed in too (by the nearer of the
            # base and the landing), so the model that sends the step has seen where it goes.
            return self._step(inp, relearn=relearn, landing=U_next)
        held_on = 0   # fans the step would have switched off, taken half way down instead
        if self.off_margin > 0 and self.idle_below > self.bounds.u_min:
            # A fan switched off from a running command is a change the prior extrapolates to
            # (the run's maps seldom show it; the dead band, an idle disc's backflow): the step
            # does it only for a gain the sweep can tell from the same step with the fan half way down
            half = 0.5 * U_b
            switched = on & (half >= self.idle_below) & (U_next <= self.bounds.u_min)
            if switched.any():
                # half way down, still running: the next sweep shows the fan there, and a fan that
                # should be off is off two or three steps later
                held_lo, held_hi = lo.copy(), hi.copy()
                held_lo[switched] = held_hi[switched] = half[switched]
                U_held, pred_held, ridge_held = solve(held_lo, held_hi)
                extra = float(np.mean(pred_held ** 2)) - float(np.mean(pred_c ** 2))
                if extra < self.off_margin * err_noise:
                    U_next, pred_c, ridge = U_held, pred_held, ridge_held
                    held_on = int(switched.sum())
        # the gain is predicted on the (pooled) residual; the error it is later compared with
        # is one map's, so the prediction is stated as one map would measure it
        improvement = float(np.mean(r_b ** 2)) - float(np.mean(pred_c ** 2))
        predicted_error = float(errors[b]) - improvement
        stop, reason = stop_rule(inp.k, improvement, inp.std, history)
        if restarted:   # a new start: what the steps before it found does not count
            stop, reason = False, ''
        if not stop and history and rho is not None and radius <= self.radius_min * (1 + 1e-9) and inp.k + 1 >= stop_rule.min_iterations:
            stop, reason = True, (f'the trust radius has shrunk to its minimum {self.radius_min:g}: '
                                  f'the predicted gains are not realised, the rest is model error')
        info = {'method': self.method, 'mode': mode, 'base_k': int(b), 'base_error': float(errors[b]),
                'predicted_error': predicted_error, 'predicted_improvement': float(improvement),
                'estimate_noise': float(err_noise), 'radius': float(radius), 'pooled_maps': pooled,
                'rho': None if rho is None else float(rho), 'accepted': bool(accepted),
                'secant_pairs': 0 if secant is None else int(secant.n_pairs_),
                'quiet': bool(stop_rule.quiet(improvement, inp.std)), 'stop': bool(stop),
                'load_slope': float(slope), 'spread_share': float(spread), 'curve': bool(curved), 'shared_curve': bool(shared_curve), 'level_map': bool(n_level and fit_from < n_level),
                'level_maps': n_level if fit_from < n_level else 0,
                'commissioning_maps': len(broad) if mode == 'shape' else 0,
                'commissioning_weight': round(float(sum(w for _, w in kept)), 4) if mode == 'shape' else 0.0,
                'stop_reason': reason, 'ridge': ridge,
                'held_on': held_on, 'from_level': from_level}
        if relearn is not None:
            info['relearned'] = relearn.to_json()
        if landing is not None:
            info['landing'] = [float(u) for u in landing]
        # step_size, like the paper's lambda_k, is dimensionless: the fraction of a full step within
        # the first trust region (without a history it is step_fraction / (k + 1), the paper's
        # schedule); the radius itself [PWM fraction] is info['radius']
        return UpdateStep(U_next, self.step_fraction * radius / self.radius, U_next - U_k, info)


class _CurveRisk:
    """What the fans' uncertain curves add to a step's expected error [N^2, a key point's mean]:

        R(U) = sum_j s_j d_j^T C_j d_j,  d_j = a_j(U_j) phi(U_j) - a_j(U_b,j) phi(U_b,j),

    with phi the curve's bumps (``ShapeFit.bumps``), C_j the posterior covariance of fan j's
    curve weights, and s_j the mean over the key points of weight x footprint^2 (the weights
    carry ``curve_risk``). The field is anchored at the base's map, so only the change from the
    base is uncertain; the fans' curves are taken as independent of each other and of the
    other parameters (the blocks between them are left out)."""

    def __init__(self, basis: FanBasis, curve_cov, U_b, weights):
        self.basis, self.cov = basis, curve_cov
        a_b, _ = basis.thrust(U_b)
        self.at_base = a_b * ShapeFit.bumps(U_b)[0]              # (K, n)
        shape = basis.shape.toarray() if sp.issparse(basis.shape) else np.asarray(basis.shape)
        self.scale = np.mean(np.asarray(weights, float)[:, None] * shape ** 2, axis=0)   # (n,)

    def __call__(self, U):
        """R(U), and per fan the curvature and slope of its own term in its move (for the
        bounded step's Gauss-Newton model)."""
        a, da = self.basis.thrust(U)
        phi, dphi = ShapeFit.bumps(U)
        d = (a * phi - self.at_base).T                           # (n, K)
        g = (da * phi + a * dphi).T                              # (n, K)
        Cd = np.einsum('jkl,jl->jk', self.cov, d)
        Cg = np.einsum('jkl,jl->jk', self.cov, g)
        value = float(np.sum(self.scale * np.sum(d * Cd, axis=1)))
        return value, self.scale * np.sum(g * Cg, axis=1), self.scale * np.sum(g * Cd, axis=1)


def _path(objective, U_from, U_to, basis: FanBasis | None = None, points: int = 21):
    """The commands and the objective at ``points`` steps along the way U_from -> U_to: straight
    in the fans' thrusts when ``basis`` is given (the prior's thrust curves, each monotone), where
    the corrected prior is convex but for what the fit bent (each fan's curve, the load slope),
    else straight in PWM."""
    ts = np.linspace(0.0, 1.0, points)
    if basis is None:
        Us = [U_from + t * (U_to - U_from) for t in ts]
    else:
        a0, a1 = basis.thrust(U_from)[0], basis.thrust(U_to)[0]
        lo, hi = np.minimum(U_from, U_to), np.maximum(U_from, U_to)
        Us = [U_from.copy(), *basis.invert(a0 + ts[1:-1, None] * (a1 - a0), lo, hi), U_to.copy()]
    return Us, np.array([objective(U) for U in Us])


def _ridge(objective, U_from, U_to, share: float, noise: float, basis=None) -> dict | None:
    """The highest point of the objective on the way U_from -> U_to (``_path``) when it rises
    above its value at U_from by more than ``share`` of that value and ``noise`` [N^2], and by
    more than the way's end promises to gain: {'t', 'height', 'start', 'end'}; None when the
    way has no such ridge."""
    _, f = _path(objective, U_from, U_to, basis)
    top = int(np.argmax(f))
    if f[top] <= f[0] * (1.0 + share) + noise or f[top] - f[0] <= f[0] - f[-1]:
        return None
    return {'t': round(top / (len(f) - 1), 3), 'height': round(float(f[top]), 6), 'start': round(float(f[0]), 6),
            'end': round(float(f[-1]), 6)}


def _before_ridge(objective, U_from, U_to, share: float, noise: float, basis=None):
    """The best command on the way U_from -> U_to (``_path``) before the objective first rises
    above its value at U_from by ``share`` of it and ``noise``; U_to when it never does."""
    Us, f = _path(objective, U_from, U_to, basis)
    over = np.flatnonzero(f > f[0] * (1.0 + share) + noise)
    if not len(over):
        return U_to
    return Us[int(np.argmin(f[:over[0]]))]


def is_level(U, enabled, tol: float = 1e-6) -> bool:
    """Whether commands U [fraction] run every enabled fan at one command above 0."""
    u = np.asarray(U, float)[np.asarray(enabled, bool)]
    return bool(u.size and u.min() > 0 and u.max() - u.min() <= tol)


def _pooled_residual(maps, window, b, near, noise2, M_vals, M_b, within):
    """The base map's residual F - F_des [N] averaged with the maps near it, and how many maps
    went in.

    Near the optimum a step moves the fans by less than one sweep's noise can resolve: built
    on the base's map alone it chases that map's noise, and the run wanders about the optimum
    instead of settling. The maps of the window whose commands all lie within ``within`` [PWM
    fraction] of the base's are moved to the base's commands by the corrected model (r_i -
    (M(U_i) - M(U_b))) and averaged per key point, weighted by near_i / (noise_std^2 + std_i^2),
    so the noise falls with the number of sweeps there while the model's error over such short
    moves stays small."""
    U_b = maps[b][0]
    members = [i for i in window
               if i == b or (within > 0 and np.max(np.abs(maps[i][0] - U_b)) <= within)]
    if len(members) < 2:
        return maps[b][1], 1
    weights = [near[i] / noise2[i] for i in members]
    total = np.sum(weights, axis=0)
    moved = sum(w * (maps[i][1] - (M_vals[i] - M_b)) for w, i in zip(weights, members))
    return moved / total, len(members)
