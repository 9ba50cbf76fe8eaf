"""The prior factorised fan by fan (``FanBasis``): the form in which the adaptive update
(``adaptive``) corrects the prior and steps.

    Phi(U, z_i) = offset_i + sum_j a_j(U_j) g_j(z_i)

g_j is fan j's footprint at the key points, a_j its PWM-to-force curve; the basis also holds the
footprint's first-order changes (the jet moved along x, y, widened) that ``ShapeFit`` fits.
Walls above ``SPARSE_PAIRS`` (key point, fan) pairs or ``SPARSE_FANS`` fans keep the footprints
as sparse matrices.

Units: commands U are fractions 0..1 of full PWM, one per fan; forces [N] at the key points
[m, tunnel frame].
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..core.errors import ConfigError

#: Above this many (key point, fan) pairs, or this many fans, the prior's footprints are kept
#: as sparse matrices and the rule takes its large-wall path (per-fan gains, a QP in thrust space).
SPARSE_PAIRS = 2_000_000
SPARSE_FANS = 64
#: (fan, fan) pairs per block when per-fan thrust curves are read from the term.
_PAIRS_PER_BLOCK = 1 << 21
#: Commands at which a prior without a closed-form thrust curve is tabulated per fan (value and
#: slope), between which ``FanBasis.thrust`` interpolates (cubic Hermite: exact at the nodes and
#: for curves up to cubic; where a curve has a kink, an ESC's dead band, it is off by up to
#: about its slope x the spacing / 8 within that one interval).
_TABLE_POINTS = 501


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
        self._table = None   # (values, slopes), each (_TABLE_POINTS, n), once asked for
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
    def shape_means(self) -> np.ndarray:
        """m_j (n,): each fan's footprint's mean over the key points [N per unit thrust]."""
        return np.asarray(self.shape.mean(axis=0)).ravel()

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
        a, da = self._thrust_rows(U[None, :])
        return a[0], da[0]

    def _evaluated(self, Us):
        """a_j and a_j' (each (m, n)) for the rows of Us (m, n), from the term itself: each fan
        alone at its command, at its peak key point, less the field with every fan off."""
        m, n = Us.shape
        out, der = np.empty((m, n)), np.empty((m, n))
        fans = np.tile(np.arange(n), m)
        step = max(1, _PAIRS_PER_BLOCK // n)
        for lo in range(0, m * n, step):
            pick = np.arange(lo, min(m * n, lo + step))
            j = fans[pick]
            rows = np.zeros((len(pick), n))
            rows[np.arange(len(pick)), j] = Us.ravel()[pick]
            v, J = self.term.value_and_jacobian(rows, self.peak_points[j])
            base = self.term(np.zeros((len(pick), n)), self.peak_points[j])
            out.ravel()[pick] = v - base
            der.ravel()[pick] = J[np.arange(len(pick)), j]
        if m == 1:
            return out[0], der[0]
        return out, der

    def _interpolated(self, U):
        """a_j(U_j), a_j'(U_j) for U in [0, 1]: cubic Hermite between the tabulated commands
        (a prior's term costs a model evaluation per call; the update asks hundreds of times)."""
        if self._table is None:
            grid = np.linspace(0.0, 1.0, _TABLE_POINTS)
            self._table = self._evaluated(np.repeat(grid[:, None], self.n_fans, axis=1))
        values, slopes = self._table
        h = 1.0 / (_TABLE_POINTS - 1)
        i = np.minimum((U / h).astype(int), _TABLE_POINTS - 2)
        t = U / h - i
        cols = np.arange(self.n_fans)
        y0, y1 = values[i, cols], values[i + 1, cols]
        m0, m1 = slopes[i, cols] * h, slopes[i + 1, cols] * h
        t2, t3 = t * t, t * t * t
        a = (2 * t3 - 3 * t2 + 1) * y0 + (t3 - 2 * t2 + t) * m0 + (-2 * t3 + 3 * t2) * y1 + (t3 - t2) * m1
        da = ((6 * t2 - 6 * t) * y0 + (3 * t2 - 4 * t + 1) * m0 + (-6 * t2 + 6 * t) * y1
              + (3 * t2 - 2 * t) * m1) / h
        return a, da

    def invert(self, t, lo, hi, iterations: int = 40) -> np.ndarray:
        """Commands U in [lo, hi] (n,) with a_j(U_j) = t_j [N] (bisection safeguarded Newton;
        a_j is non-decreasing, see ``monotone``); t outside [a(lo), a(hi)] gives lo or hi.
        t may hold several rows (m, n): each is solved as it would be alone (its own stop), in
        one batch of array operations."""
        t = np.asarray(t, dtype=float)
        if t.ndim == 1:
            return self._invert_rows(t[None, :], lo, hi, iterations)[0]
        return self._invert_rows(t, lo, hi, iterations)

    def _thrust_rows(self, U):
        """a_j and a_j' (each (m, n)) for the rows of U (m, n): the prior's polynomial curves
        where it has them, else the tabulated curves for rows inside [0, 1] and the term itself
        for the others."""
        if self._poly is not None:
            c, scale = self._poly
            P = c[:, 0] + U * (c[:, 1] + U * c[:, 2])
            return (P - c[:, 0]) * scale, (c[:, 1] + 2.0 * c[:, 2] * U) * scale
        inside = np.all((U >= 0.0) & (U <= 1.0), axis=1)
        a, da = np.empty_like(U), np.empty_like(U)
        if inside.any():
            a[inside], da[inside] = self._interpolated(U[inside])
        if not inside.all():
            out = self._evaluated(U[~inside])
            a[~inside], da[~inside] = (o.reshape(-1, U.shape[1]) for o in out)
        return a, da

    def _invert_rows(self, t, lo, hi, iterations):
        m = t.shape[0]
        lo = np.broadcast_to(np.asarray(lo, dtype=float), t.shape).copy()
        hi = np.broadcast_to(np.asarray(hi, dtype=float), t.shape).copy()
        a_lo, _ = self._thrust_rows(lo)
        a_hi, _ = self._thrust_rows(hi)
        span = np.maximum(a_hi - a_lo, 1e-12)
        U = np.clip(lo + (hi - lo) * (t - a_lo) / span, lo, hi)
        out = U.copy()
        live = np.arange(m)     # rows still iterating
        for _ in range(iterations):
            Ul, tl = U[live], t[live]
            a, da = self._thrust_rows(Ul)
            f = a - tl
            lo_l = np.where(f < 0, Ul, lo[live])
            hi_l = np.where(f > 0, Ul, hi[live])
            newton = Ul - f / np.where(da > 1e-12, da, np.inf)
            inside = (newton > lo_l) & (newton < hi_l) & np.isfinite(newton)
            U_new = np.where(inside, newton, 0.5 * (lo_l + hi_l))
            done = np.max(np.abs(U_new - Ul), axis=1) < 1e-9
            out[live[done]] = U_new[done]
            lo[live], hi[live], U[live] = lo_l, hi_l, U_new
            live = live[~done]
            if not live.size:
                return out
        out[live] = U[live]     # rows that did not settle: their last iterate
        return out

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
    paper's prior (FanJets, CentralRing and sums of them, each fan in one term, jets possibly
    moved by a ``FanShift``, as ``model.sweep_prior`` moves them all); else None.
    Lets a 1,296-fan wall read every fan's curve in O(n) instead of O(n^2) term evaluations."""
    from ..model import CentralRing, FanJets, FanShift, Sum
    n = term.n_fans
    out = np.zeros((n, 3))
    owner = np.zeros(n, dtype=int)
    stack = [term]
    while stack:
        t = stack.pop()
        if isinstance(t, Sum):
            stack += [t.k1, t.k2]
        elif type(t) is FanShift:   # moves where jets land, not the fans' curves
            stack.append(t.inner)
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
