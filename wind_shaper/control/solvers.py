"""The improved update rule (``AdaptiveUpdate``) and its stopping rule.

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
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from ..core.errors import ConfigError
from .secant import SecantCorrection
from .update import CommandBounds, UpdateInput, UpdateStep

#: Above this many (key point, fan) pairs, or this many fans, the prior's footprints are kept
#: as sparse matrices and the rule takes its large-wall path (per-fan gains, a QP in thrust space).
SPARSE_PAIRS = 2_000_000
SPARSE_FANS = 64
#: (fan, fan) pairs per block when per-fan thrust curves are read from the term.
_PAIRS_PER_BLOCK = 1 << 21


# -- the prior, fan by fan ---------------------------------------------------------------------
class FanBasis:
    """A separable prior at fixed key points, fan by fan:

        Phi(U, z_i) = offset_i + sum_j a_j(U_j) g_j(z_i)

    g_j (N,) is fan j's footprint, 1 at its peak key point z*_j; a_j(u) = Phi(u e_j, z*_j) -
    Phi(0, z*_j) [N] its PWM-to-force curve there. Besides g (``shape``), the basis holds the
    footprint's first-order changes: ``dx``, ``dy`` (moving the jet by 1 m along x, y) and
    ``dw`` (widening it by 100 % about its centre), each (N, n_fans), dense or sparse.

    Built from any ``Term`` whose fans superpose (``from_term`` checks that and refuses terms
    that do not, e.g. a swirl that turns the whole field with the thrust balance).
    """

    def __init__(self, term, key_points, offset, shape, dx, dy, dw, peak_points, poly=None):
        self.term = term
        self.key_points = key_points
        self.offset, self.shape, self.dx, self.dy, self.dw = offset, shape, dx, dy, dw
        self.peak_points = peak_points
        self.n_fans = term.n_fans
        self._thrust_cache = {}
        self._poly = poly  # (coefficients (n, 3), G_j(z*_j) (n,)) of the paper's prior, or None

    @property
    def sparse(self) -> bool:
        return sp.issparse(self.shape)

    @classmethod
    def from_term(cls, term, key_points, *, u_ref: float = 0.5, h: float = 1e-3,
                  tol: float = 1e-4, sparse: bool | None = None) -> 'FanBasis':
        """Factorise ``term`` at ``key_points`` (N, 2) [m]. u_ref: commands [fraction] at which
        the footprints are read; h: spatial step [m] of the derivative bases; tol: relative
        footprint value below which a sparse basis drops an entry. Raises ConfigError if the
        term is not separable over fans."""
        kp = np.asarray(key_points, dtype=float)
        n, N = term.n_fans, len(kp)
        sparse = (n * N > SPARSE_PAIRS or n > SPARSE_FANS) if sparse is None else sparse
        U_ref = np.full(n, u_ref)
        shifts = {'0': (0.0, 0.0), 'x+': (h, 0.0), 'x-': (-h, 0.0), 'y+': (0.0, h), 'y-': (0.0, -h)}
        if sparse:
            J = {k: term.sparse_jacobian(U_ref, kp + np.array(v), tol) for k, v in shifts.items()}
            J0 = J['0']
            peak_idx = np.asarray(abs(J0).argmax(axis=0)).ravel()
            peak = np.asarray(J0[peak_idx, np.arange(n)]).ravel()
        else:
            J = {k: term.jacobian(U_ref, kp + np.array(v)) for k, v in shifts.items()}
            J0 = J['0']
            peak_idx = np.argmax(np.abs(J0), axis=0)
            peak = J0[peak_idx, np.arange(n)]
        live = np.abs(peak) > 0
        scale = np.where(live, 1.0 / np.where(live, peak, 1.0), 0.0)
        S = sp.diags(scale) if sparse else scale[None, :]

        def norm(A):
            return (A @ S).tocsc() if sparse else A * S

        shape = norm(J0)
        gx = norm(J['x+'] - J['x-']) * (1.0 / (2 * h))
        gy = norm(J['y+'] - J['y-']) * (1.0 / (2 * h))
        centres = _centres(shape, kp)
        if sparse:
            coo = shape.tocoo()
            rx = sp.csc_matrix((kp[coo.row, 0] - centres[coo.col, 0], (coo.row, coo.col)), shape=shape.shape)
            ry = sp.csc_matrix((kp[coo.row, 1] - centres[coo.col, 1], (coo.row, coo.col)), shape=shape.shape)
            # r . grad g on the union of patterns: evaluate rx, ry on gx's pattern
            gxc, gyc = gx.tocoo(), gy.tocoo()
            dw = -(sp.csc_matrix(((kp[gxc.row, 0] - centres[gxc.col, 0]) * gxc.data, (gxc.row, gxc.col)), shape=shape.shape)
                   + sp.csc_matrix(((kp[gyc.row, 1] - centres[gyc.col, 1]) * gyc.data, (gyc.row, gyc.col)), shape=shape.shape))
            del rx, ry
            dx, dy = -gx, -gy
        else:
            rx = kp[:, 0:1] - centres[:, 0]
            ry = kp[:, 1:2] - centres[:, 1]
            dw = -(rx * gx + ry * gy)
            dx, dy = -gx, -gy
        coeffs = _fan_polynomials(term)
        if coeffs is not None:
            # the paper's prior: a_j(u) = (P_j(u) - P_j(0)) G_j(z*_j), and G_j(z*_j) = J_j(z*_j) / P_j'(u_ref)
            dP = coeffs[:, 1] + 2.0 * coeffs[:, 2] * u_ref
            scale = np.where(np.abs(dP) > 1e-12, peak / np.where(np.abs(dP) > 1e-12, dP, 1.0), 0.0)
            offset = np.asarray(shape @ (coeffs[:, 0] * scale)).ravel()
            poly = (coeffs, scale)
        else:
            offset = np.concatenate([np.asarray(term(np.zeros(n), kp[lo:lo + 4096]), dtype=float)
                                     for lo in range(0, N, 4096)])
            poly = None
        basis = cls(term, kp, offset, shape, dx, dy, dw, kp[peak_idx], poly)
        basis._check_separable(live)
        return basis

    @property
    def rot(self):
        """(N, n) change of each footprint when the field turns by +1 rad (counter-clockwise
        seen from above) about the tunnel axis: x dy - y dx [per rad]."""
        if not hasattr(self, '_rot'):
            x, y = self.key_points[:, 0], self.key_points[:, 1]
            if self.sparse:
                self._rot = (sp.diags(x) @ self.dy - sp.diags(y) @ self.dx).tocsc()
            else:
                self._rot = x[:, None] * self.dy - y[:, None] * self.dx
        return self._rot

    @property
    def gram(self):
        """S^T S (n, n) of the footprints (sparse for a sparse basis), computed once."""
        if not hasattr(self, '_gram'):
            self._gram = (self.shape.T @ self.shape).tocsr() if self.sparse else self.shape.T @ self.shape
        return self._gram

    @property
    def col_sums(self) -> np.ndarray:
        """S^T 1 (n,): each footprint summed over the key points."""
        return np.asarray(self.shape.sum(axis=0)).ravel()

    @property
    def spin(self) -> np.ndarray:
        """(n,) +1 for CCW fans, -1 for CW (seen from above)."""
        return self.term.fans.spin_sign

    def thrust(self, U) -> tuple[np.ndarray, np.ndarray]:
        """a_j(U_j) [N] and a_j'(U_j) [N per unit PWM], each (n_fans,)."""
        U = np.asarray(U, dtype=float)
        key = U.tobytes()
        hit = self._thrust_cache.get(key)
        if hit is None:
            hit = self._thrust(U)
            if len(self._thrust_cache) > 256:
                self._thrust_cache.clear()
            self._thrust_cache[key] = hit
        return hit[0].copy(), hit[1].copy()

    def _thrust(self, U):
        if self._poly is not None:
            c, scale = self._poly
            P = c[:, 0] + U * (c[:, 1] + U * c[:, 2])
            return (P - c[:, 0]) * scale, (c[:, 1] + 2.0 * c[:, 2] * U) * scale
        n = self.n_fans
        out, der = np.empty(n), np.empty(n)
        step = max(1, _PAIRS_PER_BLOCK // n)
        for lo in range(0, n, step):
            idx = np.arange(lo, min(n, lo + step))
            rows = np.zeros((len(idx), n))
            rows[np.arange(len(idx)), idx] = U[idx]
            v, J = self.term.value_and_jacobian(rows, self.peak_points[idx])
            base = self.term(np.zeros((len(idx), n)), self.peak_points[idx])
            out[idx] = v - base
            der[idx] = J[np.arange(len(idx)), idx]
        return out, der

    def invert(self, t, lo, hi, iterations: int = 40) -> np.ndarray:
        """Commands U in [lo, hi] (n,) with a_j(U_j) = t_j [N] (bisection safeguarded Newton;
        a_j is non-decreasing, see ``monotone``); t outside [a(lo), a(hi)] gives lo or hi."""
        lo, hi = np.array(lo, dtype=float), np.array(hi, dtype=float)
        a_lo, _ = self.thrust(lo)
        a_hi, _ = self.thrust(hi)
        span = np.maximum(a_hi - a_lo, 1e-12)
        U = np.clip(lo + (hi - lo) * (t - a_lo) / span, lo, hi)
        for _ in range(iterations):
            a, da = self.thrust(U)
            f = a - t
            lo = np.where(f < 0, U, lo)
            hi = np.where(f > 0, U, hi)
            newton = U - f / np.where(da > 1e-12, da, np.inf)
            inside = (newton > lo) & (newton < hi) & np.isfinite(newton)
            U_new = np.where(inside, newton, 0.5 * (lo + hi))
            if np.max(np.abs(U_new - U)) < 1e-9:
                return U_new
            U = U_new
        return U

    @property
    def monotone(self) -> bool:
        """True if every fan's a_j(u) is non-decreasing on [0, 1] (checked on a grid)."""
        if not hasattr(self, '_monotone'):
            grid = np.linspace(0.0, 1.0, 11)
            vals = np.array([self.thrust(np.full(self.n_fans, u))[0] for u in grid])
            self._monotone = bool(np.all(np.diff(vals, axis=0) >= -1e-9 * (1 + np.abs(vals[1:]))))
        return self._monotone

    def _check_separable(self, live):
        """Refuse terms whose fans do not superpose (the factorisation would be wrong)."""
        rng = np.random.default_rng(0)
        n = self.n_fans
        U = rng.uniform(0.1, 0.6, n)
        a, _ = self.thrust(U)
        pick = rng.choice(len(self.key_points), size=min(64, len(self.key_points)), replace=False)
        want = np.asarray(self.term(U, self.key_points[pick]), dtype=float)
        got = self.offset[pick] + np.asarray(self.shape[pick] @ a).ravel()
        scale = max(float(np.max(np.abs(want - self.offset[pick]))), 1e-9)
        if np.max(np.abs(want - got)) > 1e-3 * scale:
            raise ConfigError('the prior is not a sum of per-fan footprints (fans do not superpose), '
                              'so the per-fan shape correction cannot be used: set '
                              'shaping.update.correction to none')


def _fan_polynomials(term):
    """(n_fans, 3) PWM-to-force polynomial c0 + c1 U + c2 U^2 of each fan, if ``term`` is the
    paper's prior (FanJets, CentralRing and sums of them, each fan in one term); else None.
    Lets a 1,296-fan wall read every fan's curve in O(n) instead of O(n^2) term evaluations."""
    from ..model.terms import CentralRing, FanJets, Sum
    n = term.n_fans
    out = np.zeros((n, 3))
    owner = np.zeros(n, dtype=int)
    stack = [term]
    while stack:
        t = stack.pop()
        if isinstance(t, Sum):
            stack += [t.k1, t.k2]
        elif type(t) is FanJets:
            members = np.array([g in t.groups for g in t.fans.groups])
            for group, c in (('higher', t.thrust_higher), ('lower', t.thrust_lower)):
                rows = members & t.fans.group_mask(group)
                out[rows] = c
                owner += rows
        elif type(t) is CentralRing:
            rows = t.fans.group_mask('central')
            out[rows] = t.thrust
            owner += rows
        else:
            return None
    return out if np.all(owner <= 1) else None


def _centres(shape, kp) -> np.ndarray:
    """Footprint centres (n, 2) [m]: the |g|-weighted mean key point of each fan."""
    if sp.issparse(shape):
        A = abs(shape)
        w = np.asarray(A.sum(axis=0)).ravel()
        c = np.column_stack([np.asarray(A.T @ kp[:, 0]).ravel(), np.asarray(A.T @ kp[:, 1]).ravel()])
    else:
        A = np.abs(shape)
        w = A.sum(axis=0)
        c = A.T @ kp
    return c / np.where(w > 0, w, 1.0)[:, None]


# -- the per-fan correction ----------------------------------------------------------------------
BASES = ('gain', 'x', 'y', 'width')


@dataclass(frozen=True)
class ShapeFit:
    """Per-fan correction of a separable prior, fitted to field maps by ridge regression:

        M(U, z) = offset(z) + c0 + sum_j a_j(U_j) [gain_j g_j + x_j dx_j + y_j dy_j + width_j dw_j](z)

    gain_j [-] (prior 1), x_j, y_j [m] (where fan j's jet lands, prior 0), width_j [-] (relative
    widening, prior 0) and c0 [N] (a uniform offset, prior 0) have independent Gaussian priors
    with the standard deviations below; the maps' noise is ``noise_std`` [N] per key point.
    bases: which of ('gain', 'x', 'y', 'width') to fit.

    swirl: also fit one global term, the whole field turning about the tunnel axis by
    phi(U) = swirl_gain * sum_j s_j a_j(U_j) / sum_j a_j(U_j) [rad] (s_j = +1 for CCW fans, -1
    for CW), the residual swirl the honeycomb leaves when CW and CCW thrusts are unbalanced
    (the workbench's ``Swirl`` hypothesis, linearised in phi); prior 0 +- swirl_sd [rad].
    """

    bases: tuple = BASES
    swirl: bool = False
    gain_sd: float = 0.2
    shift_sd: float = 0.02
    width_sd: float = 0.15
    offset_sd: float = 0.5
    swirl_sd: float = 0.5
    noise_std: float = 0.1

    def prior(self, n: int):
        mean = np.concatenate([[0.0]] + [np.full(n, 1.0 if b == 'gain' else 0.0) for b in self.bases]
                              + [[0.0]] * self.swirl)
        sd = {'gain': self.gain_sd, 'x': self.shift_sd, 'y': self.shift_sd, 'width': self.width_sd}
        std = np.concatenate([[self.offset_sd]] + [np.full(n, sd[b]) for b in self.bases]
                             + [[self.swirl_sd]] * self.swirl)
        return mean, std

    @staticmethod
    def balance(basis: 'FanBasis', a, da=None):
        """w = sum s_j a_j / sum a_j [-] and, with da, dw/dU (n,)."""
        total = float(np.sum(a))
        if total <= 1e-9:
            return 0.0, (None if da is None else np.zeros_like(a))
        net = float(basis.spin @ a)
        w = net / total
        if da is None:
            return w, None
        return w, da * (basis.spin * total - net) / total ** 2

    def swirl_gain(self, theta) -> float:
        return float(theta[-1]) if self.swirl else 0.0

    def matrices(self, basis: FanBasis):
        table = {'gain': basis.shape, 'x': basis.dx, 'y': basis.dy, 'width': basis.dw}
        return [table[b] for b in self.bases]

    def fit(self, basis: FanBasis, maps, enabled) -> np.ndarray:
        """theta = [c0, then one block of n_fans per basis] from maps [(U (n,), F (N,), w (N,))]."""
        n = basis.n_fans
        mats = self.matrices(basis)
        mean, std = self.prior(n)
        P = len(mean)
        frozen = np.concatenate([[False]] + [~np.asarray(enabled, bool)] * len(mats) + [[False]] * self.swirl)
        if basis.sparse:
            blocks, rhs = [], []
            for U, F, w in maps:
                a, _ = basis.thrust(U)
                sw = np.sqrt(w)
                cols = [sp.csc_matrix(sw[:, None])] + [sp.diags(sw) @ (B @ sp.diags(a)) for B in mats]
                if self.swirl:
                    cols.append(sp.csc_matrix((sw * self.balance(basis, a)[0] * (basis.rot @ a))[:, None]))
                blocks.append(sp.hstack(cols, format='csr'))
                rhs.append(sw * (F - basis.offset))
            X = sp.vstack(blocks, format='csr')
            y = np.concatenate(rhs)
            A = (X.T @ X).tocsc() + sp.diags((self.noise_std / std) ** 2)
            b = X.T @ (y - X @ mean)
            keep = np.flatnonzero(~frozen)
            theta = mean.copy()
            theta[keep] += spsolve(A[keep][:, keep].tocsc(), b[keep])
            return theta
        A = np.zeros((P, P))
        b = np.zeros(P)
        cache = basis.__dict__.setdefault('_normal_cache', {})
        if len(cache) > 64:
            cache.clear()
        for U, F, w in maps:
            key = (self.bases, self.swirl, U.tobytes(), F.tobytes(), w.tobytes())
            hit = cache.get(key)
            if hit is None:
                a, _ = basis.thrust(U)
                X = np.column_stack([np.ones(len(F))] + [B * a for B in mats]
                                    + [self.balance(basis, a)[0] * (basis.rot @ a)] * self.swirl)
                Xw = X * w[:, None]
                hit = cache[key] = (X.T @ Xw, Xw.T @ (F - basis.offset - X @ mean))
            A += hit[0]
            b += hit[1]
        A += np.diag((self.noise_std / std) ** 2)
        keep = ~frozen
        theta = mean.copy()
        theta[keep] += np.linalg.solve(A[np.ix_(keep, keep)], b[keep])
        return theta

    def shape_matrix(self, basis: FanBasis, theta):
        """sum_b B_b diag(theta_b): (N, n) footprints of the corrected prior per unit a_j."""
        n = basis.n_fans
        out = None
        for i, B in enumerate(self.matrices(basis)):
            t = theta[1 + i * n:1 + (i + 1) * n]
            part = B @ sp.diags(t) if sp.issparse(B) else B * t
            out = part if out is None else out + part
        return out.tocsc() if sp.issparse(out) else out


# -- the stopping rule ---------------------------------------------------------------------------
@dataclass(frozen=True)
class StoppingRule:
    """When more iterations will not help.

    The next step's predicted improvement of the error [N^2] is compared with the noise of the
    error estimate: with per-key-point estimate noise sigma_i = sqrt(std_i^2 + floor^2) [N]
    (GP standard deviation, floored), a step whose predicted gain is below ``factor`` x
    mean(sigma^2) could not be told apart from noise by the next sweep. The rule fires after
    ``patience`` such iterations in a row, never before ``min_iterations`` updates.
    """

    factor: float = 0.5
    floor: float = 0.05
    patience: int = 1
    min_iterations: int = 2

    def __post_init__(self):
        if not (self.factor >= 0 and self.floor >= 0 and self.patience >= 1 and self.min_iterations >= 0):
            raise ConfigError(f'stopping rule needs factor, floor >= 0, patience >= 1, '
                              f'min_iterations >= 0; got {self}')

    def noise(self, std) -> float:
        """mean(std^2 + floor^2) [N^2]: the error a sweep cannot resolve."""
        s2 = 0.0 if std is None else float(np.mean(np.asarray(std, dtype=float) ** 2))
        return s2 + self.floor ** 2

    def quiet(self, predicted_improvement: float, std) -> bool:
        """True if this step's predicted improvement [N^2] is below the noise."""
        return predicted_improvement < self.factor * self.noise(std)

    def __call__(self, k: int, predicted_improvement: float, std, history=()) -> tuple[bool, str]:
        """(stop, reason) at iteration k, given the earlier iterations' ``info['quiet']``."""
        quiet = self.quiet(predicted_improvement, std)
        streak = 1 if quiet else 0
        if quiet:
            for past in reversed(tuple(history)):
                if not dict(past.info).get('quiet', False):
                    break
                streak += 1
        if k + 1 < self.min_iterations or streak < self.patience:
            return False, ''
        return True, (f'predicted improvement {predicted_improvement:.2e} N^2 is below '
                      f'{self.factor:g} x the estimate noise {self.noise(std):.2e} N^2 for '
                      f'{streak} iteration(s)')


# -- the rule ------------------------------------------------------------------------------------
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
    fit and the secant use, the most recent first; weighting: weigh key points by
    1 / (1 + (std / noise_std)^2); damping: Marquardt damping of every step (a fan's move
    costs damping x its column's squared norm; keeps nearly collinear fans of a dense wall
    from trading large opposite moves); idle_below [fraction]: a command below this is sent as
    u_min (an ESC does not turn a propeller that slowly; with u_min = 0 the feasible set is
    {0} and [idle_below, u_max]); inner_iterations: Gauss-Newton passes on the nonlinear model
    per step; stop_factor, stop_patience: the ``StoppingRule``.
    """

    bounds: CommandBounds = CommandBounds()
    step_fraction: float = 1.0
    radius: float = 0.35
    radius_min: float = 0.01
    radius_max: float = 0.65
    correction: str = 'shape'
    fit_from: int = 2
    secant: bool = True
    secant_memory: int = 6
    secant_min_step: float = 0.02
    secant_scale: float = 0.3
    noise_std: float = 0.1
    weighting: bool = False
    damping: float = 0.05
    idle_below: float = 0.02
    locality: float | None = None
    memory: int = 8
    swirl: bool = True
    inner_iterations: int = 5
    stop_factor: float = 0.5
    stop_patience: int = 1

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

    def step(self, inp: UpdateInput) -> UpdateStep:
        on = np.asarray(inp.enabled, dtype=bool)
        U_k = self.bounds.project(inp.U, on)
        delta = np.asarray(inp.delta, dtype=float)
        N = len(delta)
        target = None if inp.target is None else np.asarray(inp.target, dtype=float)
        ref = target if target is not None else np.zeros(N)
        # every map of the run: (U, F - F_des, std). Without the target the earlier maps cannot
        # be related to this one (only F_des - F_k is known), so the history is not used.
        history = inp.history if target is not None else ()
        maps = [(np.asarray(p.U, float), np.asarray(p.mean, float) - ref,
                 None if p.std is None else np.asarray(p.std, float), dict(p.info)) for p in history]
        maps.append((U_k, -delta, None if inp.std is None else np.asarray(inp.std, float), {}))
        noise2 = [self.noise_std ** 2 + (0.0 if s is None else s ** 2) for _, _, s, _ in maps]
        weights = [np.ones(N) if not self.weighting else 1.0 / (1.0 + (0.0 if s is None else s ** 2) / self.noise_std ** 2)
                   for _, _, s, _ in maps]
        errors = np.array([float(np.mean(r ** 2)) for _, r, _, _ in maps])
        stop_rule = self.stopping
        err_noise = stop_rule.noise(inp.std)

        # -- the base: the best map so far (ties go to the latest) ----------------------------
        b = int(len(maps) - 1 - np.argmin(errors[::-1]))
        if errors[-1] <= errors[b] + 0.5 * err_noise:
            b = len(maps) - 1
        U_b, r_b = maps[b][0], maps[b][1]
        if self.locality:
            near = [np.exp(-(np.max(np.abs(U - U_b)) / self.locality) ** 2) for U, _, _, _ in maps]
        else:
            near = [1.0] * len(maps)
        # the fit and the secant use the most recent `memory` maps and the base (old maps far
        # from the operating point add little and cost time)
        window = sorted(set(range(max(0, len(maps) - self.memory), len(maps))) | {b})

        # -- the prior model M(U) and its Jacobian, corrected by the maps ----------------------
        basis = self._basis(inp)
        fitted = len(maps) >= self.fit_from
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
                           swirl=self.swirl and not basis.sparse, noise_std=self.noise_std)
            if fitted:
                abs_maps = [(maps[i][0], maps[i][1] + ref, near[i] * weights[i] / noise2[i] * self.noise_std ** 2)
                            for i in window]
                theta = fit.fit(basis, abs_maps, on)
            else:
                theta = fit.prior(basis.n_fans)[0]
            Smat = fit.shape_matrix(basis, theta)
            g_swirl = fit.swirl_gain(theta)

            def model(U):
                a, da = basis.thrust(U)
                val = np.asarray(Smat @ a).ravel()
                jac = Smat @ sp.diags(da) if sp.issparse(Smat) else Smat * da
                if g_swirl:
                    w, dw = fit.balance(basis, a, da)
                    ra = basis.rot @ a
                    val = val + g_swirl * w * ra
                    jac = jac + g_swirl * (w * (basis.rot * da) + np.outer(ra, dw))
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

        # -- trust radius from the last step's prediction ---------------------------------------
        radius, rho, accepted = self.radius, None, True
        if not history and inp.k > 0:
            # Called without the run's history (e.g. by a node that keeps none): the rule cannot
            # see whether its steps work, so the radius shrinks like the paper's schedule.
            radius = max(self.radius_min, self.radius / (inp.k + 1))
        if history:
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

        def objective(pred):
            return float(np.mean(w_b * pred ** 2))

        idx = np.flatnonzero(on)
        U_c = U_b.copy()
        pred_c, J_c = predict(U_c)
        f_c = objective(pred_c)
        if J_b is None:  # large wall: the bounded QP in thrust space is the whole step
            if idx.size:
                U_c = _thrust_space_qp(basis, gains, r_b, U_b, lo, hi, idx, self.damping)
                pred_c, _ = predict(U_c)
        elif basis is not None and idx.size and basis.monotone:
            # The corrected prior is linear in the per-fan thrusts a_j: solve the bounded
            # problem there exactly (a fan idling at PWM 0, where da/dU = 0, can come back),
            # then refine in PWM space, where the secant term lives.
            U_t = _thrust_space_step(basis, Smat, r_b, np.sqrt(w_b), U_b, lo, hi, idx, self.damping)
            pred_t, J_t = predict(U_t)
            f_t = objective(pred_t)
            if f_t < f_c:
                U_c, pred_c, J_c, f_c = U_t, pred_t, J_t, f_t
                # the convex thrust-space problem decides which limits are active: fans it put on
                # a limit stay there (at PWM 0 the model's slope is 0, so the refinement below
                # could only wander off it on noise)
                pinned = (U_t <= lo + 1e-12) | (U_t >= hi - 1e-12)
                lo, hi = np.where(pinned, U_t, lo), np.where(pinned, U_t, hi)
        for _ in range(self.inner_iterations if idx.size and J_b is not None else 0):
            du = _bounded_lsq(J_c, secant, pred_c, np.sqrt(w_b), idx, lo[idx] - U_c[idx], hi[idx] - U_c[idx],
                              self.damping)
            t, improved = 1.0, False
            while t > 1e-3:
                U_t = U_c.copy()
                U_t[idx] = np.clip(U_c[idx] + t * du, lo[idx], hi[idx])
                pred_t, J_t = predict(U_t)
                f_t = objective(pred_t)
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
        U_next = self.bounds.project(U_b + self.step_fraction * (U_c - U_b), on)
        if self.idle_below > self.bounds.u_min:
            # no ESC turns a propeller at a few percent PWM: such a command is sent as u_min
            U_next = np.where(on & (U_next < self.idle_below), self.bounds.u_min, U_next)
        if self.step_fraction < 1 or not np.array_equal(U_next, U_c):
            pred_c, _ = predict(U_next)
        predicted_error = float(np.mean(pred_c ** 2))
        improvement = errors[b] - predicted_error
        stop, reason = stop_rule(inp.k, improvement, inp.std, history)
        if not stop and history and rho is not None and radius <= self.radius_min * (1 + 1e-9) and inp.k + 1 >= stop_rule.min_iterations:
            stop, reason = True, (f'the trust radius has shrunk to its minimum {self.radius_min:g}: '
                                  f'the predicted gains are not realised, the rest is model error')
        info = {'method': self.method, 'mode': mode, 'base_k': int(b), 'base_error': float(errors[b]),
                'predicted_error': predicted_error, 'predicted_improvement': float(improvement),
                'estimate_noise': float(err_noise), 'radius': float(radius),
                'rho': None if rho is None else float(rho), 'accepted': bool(accepted),
                'secant_pairs': 0 if secant is None else int(secant.n_pairs_),
                'quiet': bool(stop_rule.quiet(improvement, inp.std)), 'stop': bool(stop),
                'stop_reason': reason}
        # step_size, like the paper's lambda_k, is dimensionless: the fraction of a full step within
        # the first trust region (without a history it is step_fraction / (k + 1), the paper's
        # schedule); the radius itself [PWM fraction] is info['radius']
        return UpdateStep(U_next, self.step_fraction * radius / self.radius, U_next - U_k, info)


_BASIS_CACHE: dict[Any, Any] = {}


def _fit_gains_sparse(basis, maps, enabled, noise_std, gain_sd, offset_sd) -> np.ndarray:
    """Per-fan gains (n,) of a sparse basis from maps [(U, F (N,), weight (scalar))]: ridge
    regression F - offset ~ c0 + S diag(a(U)) g on the footprints' Gram matrix S^T S."""
    n, N = basis.n_fans, len(basis.key_points)
    G, s1 = basis.gram, basis.col_sums
    A_g0, A_00 = np.zeros(n), 0.0
    b_g, b_0 = np.zeros(n), 0.0
    rows = np.repeat(np.arange(n), np.diff(G.indptr))
    A = np.zeros(G.nnz)
    for U, F, w in maps:
        a, _ = basis.thrust(U)
        y = F - basis.offset
        A += w * G.data * a[rows] * a[G.indices]  # diag(a) G diag(a) on G's pattern
        A_g0 += w * a * s1
        A_00 += w * N
        b_g += w * a * np.asarray(basis.shape.T @ y).ravel()
        b_0 += w * float(np.sum(y))
    A = sp.csr_matrix((A, G.indices, G.indptr), shape=G.shape)
    keep = np.flatnonzero(np.asarray(enabled, bool))
    M = np.zeros((len(keep) + 1, len(keep) + 1))
    M[1:, 1:] = A[keep][:, keep].toarray()
    M[0, 1:] = M[1:, 0] = A_g0[keep]
    M[0, 0] = A_00
    mean = np.concatenate([[0.0], np.ones(len(keep))])
    rhs = np.concatenate([[b_0], b_g[keep]]) - M @ mean
    M[np.diag_indices_from(M)] += (noise_std / np.concatenate([[offset_sd], np.full(len(keep), gain_sd)])) ** 2
    sol = mean + np.linalg.solve(M, rhs)
    gains = np.ones(n)
    gains[keep] = np.clip(sol[1:], 0.2, 5.0)  # a gain outside this range is a fit gone wrong
    return gains


def _thrust_space_qp(basis, gains, residual, U_b, lo, hi, idx, damping=0.0) -> np.ndarray:
    """Large walls: argmin_d 1/2 d^T H d + c^T d over the thrust box (L-BFGS-B), with
    H = diag(g) S^T S diag(g) from the cached Gram matrix and c = diag(g) S^T residual; the
    commands are a^-1(a(U_b) + d)."""
    from scipy.optimize import minimize
    a_b, _ = basis.thrust(U_b)
    a_lo, _ = basis.thrust(lo)
    a_hi, _ = basis.thrust(hi)
    g = gains[idx]
    G = basis.gram[idx][:, idx].tocsr()
    rows = np.repeat(np.arange(len(idx)), np.diff(G.indptr))
    # Jacobi scaling d = x / sqrt(diag H): unit diagonal, so L-BFGS-B converges in far fewer steps
    diag = np.maximum(np.asarray(G.diagonal()) * g * g, 1e-12)
    p = 1.0 / np.sqrt(diag)
    gp = g * p
    H = sp.csr_matrix((G.data * gp[rows] * gp[G.indices], G.indices, G.indptr), shape=G.shape)
    H = (H + damping * sp.eye(len(idx))).tocsr()  # Marquardt: the scaled diagonal is 1
    c = gp * np.asarray(basis.shape[:, idx].T @ residual).ravel()
    scale = 1.0 / max(float(residual @ residual), 1e-12)

    def f(x):
        Hx = H @ x
        return scale * (0.5 * x @ Hx + c @ x), scale * (Hx + c)

    lb, ub = (a_lo[idx] - a_b[idx]) / p, (a_hi[idx] - a_b[idx]) / p
    sol = minimize(f, np.zeros(len(idx)), jac=True, method='L-BFGS-B',
                   bounds=np.column_stack([lb, np.maximum(ub, lb)]),
                   options={'maxiter': 500, 'ftol': 1e-12, 'gtol': 1e-9})
    t = a_b.copy()
    t[idx] += np.clip(sol.x, lb, ub) * p
    U = U_b.copy()
    U[idx] = basis.invert(t, lo, hi)[idx]
    return U


def _thrust_space_step(basis, Smat, residual, sw, U_b, lo, hi, idx, damping=0.0) -> np.ndarray:
    """argmin_U ||sw (residual + S (a(U) - a(U_b)))|| over lo <= U <= hi, solved as a bounded
    linear least-squares problem in t = a(U) and mapped back through a^-1."""
    a_b, _ = basis.thrust(U_b)
    a_lo, _ = basis.thrust(lo)
    a_hi, _ = basis.thrust(hi)
    dt = _bounded_lsq(Smat, None, residual, sw, idx, a_lo[idx] - a_b[idx], a_hi[idx] - a_b[idx], damping)
    t = a_b.copy()
    t[idx] += dt
    U = U_b.copy()
    U[idx] = basis.invert(t, lo, hi)[idx]
    return U


def _bounded_lsq(J, secant, residual, sw, idx, lb, ub, damping: float = 0.0) -> np.ndarray:
    """argmin ||sw (J_idx du + D_idx du + residual)||^2 + damping sum_j ||sw A_j||^2 du_j^2 over
    lb <= du <= ub (the enabled fans idx; A = J + D): a bounded, Marquardt-damped
    Gauss-Newton step (the damping keeps nearly collinear fans from trading large opposite
    moves that the model cannot vouch for)."""
    A = J[:, idx]
    if secant is not None:
        A = A + secant.matrix()[:, idx]
    A = A * sw[:, None]
    b = -sw * residual
    lb = np.minimum(lb, ub)
    if np.all(ub - lb <= 0):
        return np.zeros(len(idx))
    H = A.T @ A
    H[np.diag_indices_from(H)] *= 1.0 + damping
    return box_qp(H, -(A.T @ b), lb, ub)


def box_qp(H, g, lb, ub, iterations: int = 100) -> np.ndarray:
    """argmin 1/2 x^T H x + g^T x over lb <= x <= ub for a small symmetric positive
    (semi)definite H (n, n): projected Newton with an Armijo search along the projection arc
    (Bertsekas 1982). Exact for a strictly convex problem in a few iterations."""
    n = len(g)
    H = H + (1e-12 * max(float(np.trace(H)) / max(n, 1), 1e-300)) * np.eye(n)
    x = np.clip(np.zeros(n), lb, ub)
    f = 0.5 * x @ H @ x + g @ x
    for _ in range(iterations):
        grad = H @ x + g
        tiny = 1e-12 * (1.0 + np.abs(x))
        binding = ((x <= lb + tiny) & (grad > 0)) | ((x >= ub - tiny) & (grad < 0))
        free = ~binding
        d = np.zeros(n)
        if free.any():
            d[free] = -np.linalg.solve(H[np.ix_(free, free)], grad[free])
        t, moved = 1.0, False
        while t > 1e-10:
            x_t = np.clip(x + t * d, lb, ub)
            f_t = 0.5 * x_t @ H @ x_t + g @ x_t
            if f_t <= f + 1e-4 * grad @ (x_t - x):
                moved = True
                break
            t *= 0.5
        if not moved or np.max(np.abs(x_t - x)) <= 1e-13 * (1.0 + np.max(np.abs(x))):
            x = x_t if moved else x
            break
        x, f = x_t, f_t
    return x
