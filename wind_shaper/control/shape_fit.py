"""The per-fan correction of the prior, learned from the run's field maps.

``ShapeFit`` fits each fan's gain, the landing point of its jet and its width (optionally one
global swirl term) as a linear correction of a ``FanBasis``, by ridge regression over every map
of the run: the corrected prior M(U) of the adaptive update (``adaptive``).
``_fit_gains_sparse`` is the large-wall version: per-fan gains only, on the footprints' Gram
matrix.

Units: commands U are fractions 0..1 of full PWM, one per fan; forces [N] at the key points
[m, tunnel frame].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from ..core.errors import ConfigError
from .basis import FanBasis

#: What ``ShapeFit`` can fit per fan: its gain, the landing point (x, y) of its jet, its width.
BASES = ('gain', 'x', 'y', 'width')
#: The mean command [fraction] at which the shared load slope leaves the gains as they are.
LOAD_REF = 0.3
#: Centres [PWM fraction] of the bumps of each fan's curve correction (``ShapeFit.curve_sd``),
#: and their width: a stall dip or a dead band spans 0.1-0.3 of the command.
CURVE_CENTRES = np.linspace(0.05, 0.95, 10)
CURVE_WIDTH = 0.1
#: each bump's mean over the command range 0..1, taken off it: a constant factor is the gain's
#: to fit (the bumps alone would sum to one and trade it against the gain's prior)
def _bump_means(centres, width, points):
    return np.array([np.mean(np.exp(-0.5 * ((np.linspace(0, 1, points) - c) / width) ** 2)) for c in centres])


def _bumps(U, centres, width, means):
    """phi (K, n) and dphi/dU (K, n): Gaussian bumps less their means, at each fan's command."""
    d = (np.asarray(U, float)[None, :] - centres[:, None]) / width
    phi = np.exp(-0.5 * d ** 2)
    return phi - means[:, None], -d / width * phi


_CURVE_MEANS = _bump_means(CURVE_CENTRES, CURVE_WIDTH, 201)
#: The finer bumps of the curve every fan shares (``ShapeFit.shared_curve_sd``): each map shows
#: it at every running fan's command, so it can be resolved finer than one fan's own.
SHARED_CENTRES = np.linspace(0.025, 0.975, 20)
SHARED_WIDTH = 0.05
_SHARED_MEANS = _bump_means(SHARED_CENTRES, SHARED_WIDTH, 401)


@dataclass(frozen=True)
class ShapeFit:
    """Per-fan correction of a separable prior, fitted to field maps by ridge regression:

        M(U, z) = offset(z) + c0 + sum_j a_j(U_j) [gain_j g_j + x_j dx_j + y_j dy_j + width_j dw_j](z)

    gain_j [-] (prior 1), x_j, y_j [m] (where fan j's jet lands, prior 0), width_j [-] (relative
    widening, prior 0) and c0 [N] (a uniform offset, prior 0) have independent Gaussian priors
    with the standard deviations below; the maps' noise is ``noise_std`` [N] per key point.
    bases: which of ('gain', 'x', 'y', 'width') to fit.

    gain_common_sd [-]: with it > 0 the gains are 1 + common + own_j, a deviation every enabled
    fan shares (a sagging supply, a starved inlet, air density, the sensor's scale) with sd
    gain_common_sd beside each fan's own with sd gain_sd; a fan that no map has seen running
    then moves with the others instead of staying at the prior. 0: independent gains. Dense
    priors only (a large wall's sparse fit keeps independent gains).

    load_sd [1 per unit command]: with it > 0 also fit one shared slope of the gains with the
    load, every fan's footprint scaled by 1 + load_slope (L(U) - LOAD_REF) with L the mean
    command of the enabled fans (a starved inlet or a sagging supply: each fan gives less the
    harder all of them run); prior 0 +- load_sd, and never above 0 (the fit with the slope held
    at 0 when the free fit's slope is positive: no shared supply makes a fan stronger). 0: no
    such term. Dense priors only.

    spread_sd [-]: with it > 0 also fit one shared share of every fan's force at the key points
    that lands spread evenly over them instead of in its jet, the field gaining
    spread * sum_j m_j a_j(U_j) at every key point (m_j: fan j's footprint's mean over the key
    points): a mesh screen or mixing above the fans, a recirculating core. Unlike the uniform
    offset c0 it follows the fans' total thrust, so maps at different loads tell the two apart.
    Prior 0 +- spread_sd. 0: no such term. Dense priors only.

    tilt_sd [N per 0.1 m]: with it > 0 also fit a plane across the section, t_x x + t_y y
    (x, y of the key points per 0.1 m), whatever the fans do: a warm wall's buoyant tilt, a
    draft. It never enters a prediction (the field is anchored at a measured map, where a
    constant background cancels), but left out it bends the fans' fitted gains and shifts.
    Prior 0 +- tilt_sd each. 0: none. Dense priors only.

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
    gain_common_sd: float = 0.0
    load_sd: float = 0.0
    #: the parameters' prior means (theta's layout); None: gain 1, everything else 0
    prior_mean: tuple | None = None
    #: [-] with it > 0, each fan's gain also varies with its own command, gain_j + h_j(u), h_j
    #: a sum of Gaussian bumps less their means over 0..1 (``CURVE_CENTRES``, ``CURVE_WIDTH``)
    #: with weights of prior 0 +- curve_sd: what a per-fan gain cannot hold, a
    #: stall dip or a dead band in one fan's curve, learned from the maps that ran it at
    #: different commands. 0: none. Dense priors only.
    curve_sd: float = 0.0
    #: [-] with it > 0 (and curve_sd > 0) every fan's gain also follows one curve all fans
    #: share, finer bumps (``SHARED_CENTRES``) with weights of prior 0 +- shared_curve_sd: fans of
    #: one make stall or dead-band at the same command. 0: each fan's curve on its own.
    shared_curve_sd: float = 0.0
    #: the log Bayes factor (the maps' marginal likelihood with the shared curve over without
    #: it) above which the fit bends it; -inf: always
    shared_margin: float = 10.0
    spread_sd: float = 0.0
    tilt_sd: float = 0.0

    @property
    def loaded(self) -> bool:
        return self.load_sd > 0

    @property
    def spread(self) -> bool:
        return self.spread_sd > 0

    @property
    def tilted(self) -> bool:
        return self.tilt_sd > 0

    @property
    def _tail(self) -> int:
        """theta's entries after the load slope: the spread share and the plane's two slopes."""
        return int(self.spread) + 2 * int(self.tilted)

    @property
    def curved(self) -> bool:
        return self.curve_sd > 0

    @property
    def _n_shared(self) -> int:
        return len(SHARED_CENTRES) if self.curved and self.shared_curve_sd > 0 else 0

    @staticmethod
    def shared_bumps(U):
        """phi (K2, n) and dphi/dU (K2, n): the shared curve's bumps at each fan's command."""
        return _bumps(U, SHARED_CENTRES, SHARED_WIDTH, _SHARED_MEANS)

    @staticmethod
    def bumps(U):
        """phi (K, n) and dphi/dU (K, n): the curve correction's bumps at each fan's command."""
        return _bumps(U, CURVE_CENTRES, CURVE_WIDTH, _CURVE_MEANS)

    def curve(self, theta, U, n: int):
        """h (n,) and dh/dU (n,): what each fan's curve correction adds to its gain at its
        command U (the fan's footprint is scaled by gain_j + h_j(U_j))."""
        if not self.curved:
            return np.zeros(n), np.zeros(n)
        start = 1 + len(self.bases) * n
        c = np.asarray(theta[start:start + len(CURVE_CENTRES) * n], float).reshape(len(CURVE_CENTRES), n)
        phi, dphi = self.bumps(U)
        h, dh = np.sum(c * phi, axis=0), np.sum(c * dphi, axis=0)
        if self._n_shared:
            w = np.asarray(theta[start + len(CURVE_CENTRES) * n:start + len(CURVE_CENTRES) * n + self._n_shared], float)
            phi, dphi = self.shared_bumps(U)
            h, dh = h + w @ phi, dh + w @ dphi
        return h, dh

    def prior(self, n: int):
        K = len(CURVE_CENTRES) * n * self.curved
        mean = np.concatenate([[0.0]] + [np.full(n, 1.0 if b == 'gain' else 0.0) for b in self.bases]
                              + [np.zeros(K + self._n_shared)] + [[0.0]] * self.swirl + [[0.0]] * self.loaded
                              + [[0.0]] * self.spread + [[0.0, 0.0]] * self.tilted)
        sd = {'gain': self.gain_sd, 'x': self.shift_sd, 'y': self.shift_sd, 'width': self.width_sd}
        std = np.concatenate([[self.offset_sd]] + [np.full(n, sd[b]) for b in self.bases]
                             + [np.full(K, self.curve_sd), np.full(self._n_shared, self.shared_curve_sd)]
                             + [[self.swirl_sd]] * self.swirl + [[self.load_sd]] * self.loaded
                             + [[self.spread_sd]] * self.spread + [[self.tilt_sd] * 2] * self.tilted)
        if self.prior_mean is not None:
            mean = np.asarray(self.prior_mean, dtype=float).copy()
        return mean, std

    @staticmethod
    def load(U, enabled) -> float:
        """L(U) - LOAD_REF: the enabled fans' mean command [fraction] against the reference."""
        on = np.asarray(enabled, bool)
        return float(np.mean(np.asarray(U, float)[on])) - LOAD_REF if on.any() else 0.0

    def load_slope(self, theta) -> float:
        return float(theta[-1 - self._tail]) if self.loaded else 0.0

    def spread_share(self, theta) -> float:
        return float(theta[-1 - 2 * int(self.tilted)]) if self.spread else 0.0

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
        return float(theta[-1 - self.loaded - self._tail]) if self.swirl else 0.0

    def matrices(self, basis: FanBasis):
        table = {'gain': basis.shape, 'x': basis.dx, 'y': basis.dy, 'width': basis.dw}
        return [table[b] for b in self.bases]

    def fit(self, basis: FanBasis, maps, enabled) -> np.ndarray:
        """theta = [c0, then one block of n_fans per basis] from maps [(U (n,), F (N,), w (N,))]."""
        return self._fit(basis, maps, enabled, False)[0]

    def fit_posterior(self, basis: FanBasis, maps, enabled):
        """theta as ``fit`` and its posterior covariance (P, P), in theta's units: zero rows and
        columns for what is held at its prior (a disabled fan's parameters, a rising load slope
        held at 0). None in place of the covariance for a large wall's sparse fit."""
        return self._fit(basis, maps, enabled, True)

    def _fit(self, basis: FanBasis, maps, enabled, with_cov: bool):
        n = basis.n_fans
        mats = self.matrices(basis)
        mean, std = self.prior(n)
        P = len(mean)
        frozen = np.concatenate([[False]] + [~np.asarray(enabled, bool)] * len(mats)
                                + [~np.asarray(enabled, bool)] * (len(CURVE_CENTRES) * self.curved)
                                + [np.zeros(self._n_shared, bool)]
                                + [[False]] * (self.swirl + self.loaded + self._tail))
        if basis.sparse:
            if self.curved:
                raise ConfigError('the curve correction (curve_sd) needs a dense prior; a large '
                                  'wall\'s sparse fit has per-fan gains only: set curve_sd to 0')
            for name in ('load_sd', 'spread_sd', 'tilt_sd'):
                if getattr(self, name) > 0:
                    raise ConfigError(f'{name} needs a dense prior; a large wall\'s sparse fit has '
                                      f'per-fan gains only: set {name} to 0')
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
            return theta, None
        A = np.zeros((P, P))
        b = np.zeros(P)
        cache = basis.__dict__.setdefault('_normal_cache', {})
        if len(cache) > 64:
            cache.clear()
        for U, F, w in maps:
            key = (self.bases, self.swirl, self.loaded, self.curved, self._n_shared, self.spread, self.tilted, U.tobytes(), F.tobytes(),
                   w.tobytes(), mean.tobytes())
            hit = cache.get(key)
            if hit is None:
                a, _ = basis.thrust(U)
                curve = [basis.shape * (a * phi) for phi in self.bumps(U)[0]] if self.curved else []
                curve += [basis.shape @ (a * phi) for phi in self.shared_bumps(U)[0][:self._n_shared]]
                X = np.column_stack([np.ones(len(F))] + [B * a for B in mats] + curve
                                    + [self.balance(basis, a)[0] * (basis.rot @ a)] * self.swirl
                                    + [self.load(U, enabled) * (basis.shape @ a)] * self.loaded
                                    + [np.full(len(F), float(basis.shape_means @ a))] * self.spread
                                    + [basis.key_points[:, 0] / 0.1, basis.key_points[:, 1] / 0.1] * self.tilted)
                Xw = X * w[:, None]
                hit = cache[key] = (X.T @ Xw, Xw.T @ (F - basis.offset - X @ mean))
            A += hit[0]
            b += hit[1]
        A += np.diag((self.noise_std / std) ** 2)
        keep = ~frozen
        if self.gain_common_sd > 0 and 'gain' in self.bases:
            # the gains' prior covariance gain_sd^2 I + gain_common_sd^2 1 1^T over the enabled
            # fans; its inverse (Sherman-Morrison) replaces their diagonal precision
            g = 1 + self.bases.index('gain') * n + np.flatnonzero(~frozen[1:1 + n])
            m, sd2, c2 = len(g), self.gain_sd ** 2, self.gain_common_sd ** 2
            A[np.ix_(g, g)] -= self.noise_std ** 2 * c2 / (sd2 * (sd2 + m * c2))
        if self._n_shared and self.shared_margin > -np.inf:   # -inf: bent without the test
            keep = self._shared_by_evidence(A, b, keep, n)
        theta = mean.copy()
        theta[keep] += np.linalg.solve(A[np.ix_(keep, keep)], b[keep])
        # Signs physics rules out: a shared supply or inlet can only give less as the load rises,
        # and a jet's force spread over the section only adds to it. A rising slope or a negative
        # share is other misfit (a wider start's map explained away): held at 0, and refitted.
        signed = [(P - 1 - self._tail, 1.0)] * self.loaded + [(P - 1 - 2 * int(self.tilted), -1.0)] * self.spread
        for _ in signed:
            wrong = [i for i, sign in signed if keep[i] and sign * theta[i] > 0]
            if not wrong:
                break
            keep[wrong] = False
            theta = mean.copy()
            theta[keep] += np.linalg.solve(A[np.ix_(keep, keep)], b[keep])
        if not with_cov:
            return theta, None
        # A is the posterior precision times noise_std^2 (the maps' weights are in units of it)
        cov = np.zeros((P, P))
        cov[np.ix_(keep, keep)] = self.noise_std ** 2 * np.linalg.inv(A[np.ix_(keep, keep)])
        return theta, cov

    def shared_curve_used(self, theta) -> bool:
        """Whether the corrected prior bends the curve every fan shares (``shared_curve_sd``):
        the maps' evidence favoured it here, or in the commissioning's fit this one starts from."""
        if not self._n_shared:
            return False
        n = (len(theta) - 1 - self._n_shared - self.swirl - self.loaded - self._tail) // (len(self.bases) + len(CURVE_CENTRES))
        return bool(np.any(np.asarray(theta)[self._shared_index(n)] != 0))

    def _shared_index(self, n: int) -> np.ndarray:
        start = 1 + len(self.bases) * n + len(CURVE_CENTRES) * n
        return start + np.arange(self._n_shared)

    def _shared_by_evidence(self, A, b, keep, n: int):
        """keep, with the shared curve's weights dropped (held at their prior mean) unless the
        maps' evidence (the Gaussian linear model's marginal likelihood) favours the fit with
        them: a curve all fans share is bent only where the maps show one, not to soak up other
        misfit."""
        shared = np.zeros(len(keep), bool)
        shared[self._shared_index(n)] = True
        without = keep & ~shared

        def fit_term(k):
            Ak = A[np.ix_(k, k)]
            return 0.5 * float(b[k] @ np.linalg.solve(Ak, b[k])) / self.noise_std ** 2 - 0.5 * np.linalg.slogdet(Ak)[1]

        log_bf = (fit_term(keep) - fit_term(without)
                  + 0.5 * self._n_shared * np.log(self.noise_std ** 2 / self.shared_curve_sd ** 2))
        return keep if log_bf > self.shared_margin else without

    def curve_cov(self, cov, n: int) -> np.ndarray:
        """(n, K, K): each fan's block of ``cov`` for its curve weights (``curve_sd``; the
        blocks between fans are left out)."""
        K = len(CURVE_CENTRES)
        start = 1 + len(self.bases) * n
        out = np.zeros((n, K, K))
        for j in range(n):
            ix = start + np.arange(K) * n + j
            out[j] = cov[np.ix_(ix, ix)]
        return out

    def shape_matrix(self, basis: FanBasis, theta):
        """sum_b B_b diag(theta_b): (N, n) footprints of the corrected prior per unit a_j."""
        n = basis.n_fans
        out = None
        for i, B in enumerate(self.matrices(basis)):
            t = theta[1 + i * n:1 + (i + 1) * n]
            part = B @ sp.diags(t) if sp.issparse(B) else B * t
            out = part if out is None else out + part
        if self.spread and not sp.issparse(out):
            out = out + self.spread_share(theta) * np.outer(np.ones(out.shape[0]), basis.shape_means)
        return out.tocsc() if sp.issparse(out) else out


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
