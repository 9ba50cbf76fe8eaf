"""The paper's coarse physical prior Phi_pr(U, z): the edge fans' jets (``FanJets``) plus the
central fan's ring (``CentralRing``), and ``paper_prior``, which builds it for a fan array
(``fan_effects.sweep_prior``: the same with where the whole field lands free).

Both are terms (``wind_shaper.model.terms``) registered with ``register_term``. Units: positions
[m, tunnel frame], forces [N], commands U [fraction 0..1 of full PWM].
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..core.geometry import FanArray
from .terms import Hyper, Term, register_term

__all__ = ['FanJets', 'CentralRing', 'paper_prior', 'POLY_BOUNDS', 'SIGMA_BOUNDS']


def _poly(coeffs, U):
    """Quadratic c0 + c1 U + c2 U^2 and its derivative; coeffs (..., 3) broadcast against U."""
    c0, c1, c2 = coeffs[..., 0], coeffs[..., 1], coeffs[..., 2]
    return c0 + c1 * U + c2 * U * U, c1 + 2.0 * c2 * U


def _sq_dist(Z, centres):
    """Squared distances (M, n) [m^2] from points Z (M, 2) to centres (n, 2)."""
    d = Z[:, None, :] - centres[None, :, :]
    return np.einsum('mnk,mnk->mn', d, d)


def _near_pairs(Z, centres, reach):
    """(point index, centre index, squared distance [m^2]) of every pair closer than reach [m],
    grouped by centre and sorted by point within a centre (so CSC needs no sorting)."""
    from scipy.spatial import cKDTree
    Z = np.asarray(Z, dtype=float).reshape(-1, 2)
    near = cKDTree(Z).query_ball_point(np.asarray(centres, dtype=float), reach, return_sorted=True)
    counts = np.array([len(v) for v in near], dtype=np.int64)
    rows = (np.concatenate([np.asarray(v, dtype=np.int64) for v in near]) if len(near)
            else np.zeros(0, dtype=np.int64))
    cols = np.repeat(np.arange(len(near)), counts)
    d = Z[rows] - np.asarray(centres, dtype=float)[cols]
    return rows, cols, np.einsum('ij,ij->i', d, d)


def _sparse_from_pairs(rows, cols, vals, shape):
    """CSC from pairs grouped by column with sorted rows (as ``_near_pairs`` returns them)."""
    import scipy.sparse as sp
    indptr = np.zeros(shape[1] + 1, dtype=np.int64)
    np.cumsum(np.bincount(cols, minlength=shape[1]), out=indptr[1:])
    return sp.csc_matrix((vals, rows, indptr), shape=shape)


#: Bounds of the PWM-to-force polynomial c0 + c1 U + c2 U^2 [N]: c1, c2 >= 0 keeps P
#: non-decreasing on [0, 1] (thrust never falls as PWM rises); a fitted negative slope near
#: U = 0 would make the update push a fan up to lower the force.
POLY_BOUNDS = ((-2.0, 2.0), (0.0, 100.0), (0.0, 100.0))
SIGMA_BOUNDS = (0.02, 1.0)


@register_term
class FanJets(Term):
    """Edge-fan jets: sum_j P_g(j)(U_j) exp(-d_j(z)^2 / sigma^2) over fans of ``groups``.

    P_higher, P_lower: quadratic PWM-to-force polynomials [N] (coefficients c0, c1, c2 for
    1, U, U^2) of the fans mounted higher (CCW) and lower (CW); sigma: footprint width [m] of a
    jet as seen by the plate; d_j: distance from the plate centre to fan j's hub [m].
    """

    kind = 'fan_jets'
    hypers = (Hyper('thrust_higher', 3, POLY_BOUNDS), Hyper('thrust_lower', 3, POLY_BOUNDS),
              Hyper('sigma', 1, SIGMA_BOUNDS))

    def __init__(self, fans: FanArray, thrust_higher=(0.0, 2.0, 10.0), thrust_lower=(0.0, 2.0, 9.0),
                 sigma: float = 0.15, groups: Sequence[str] = ('higher', 'lower'), fixed=()):
        self.fans = fans
        self.thrust_higher = np.asarray(thrust_higher, dtype=float)
        self.thrust_lower = np.asarray(thrust_lower, dtype=float)
        self.sigma = float(sigma)
        self.groups = tuple(groups)
        self._init_hypers(fixed)
        self._check_bounds()
        self._members = np.array([g in self.groups for g in fans.groups])
        # Per-fan polynomial coefficients (n, 3); non-members get zeros.
        coeffs = np.zeros((fans.n_fans, 3))
        coeffs[fans.group_mask('higher') & self._members] = self.thrust_higher
        coeffs[fans.group_mask('lower') & self._members] = self.thrust_lower
        self._coeffs = coeffs

    def clone(self, **overrides):
        params = self.get_params()
        params.update(overrides)
        return FanJets(self.fans, groups=self.groups, fixed=self.fixed_names, **params)

    def footprint(self, Z) -> np.ndarray:
        """exp(-d^2 / sigma^2), (M, n_fans), zero for fans outside ``groups``."""
        return np.exp(-_sq_dist(Z, self.fans.positions) / self.sigma ** 2) * self._members

    def _value_and_grad(self, U, Z, jacobian):
        G = self.footprint(Z)
        P, dP = _poly(self._coeffs, U)
        return np.sum(G * P, axis=1), (G * dP if jacobian else None)

    def sparse_jacobian(self, U, Z, tol: float = 1e-6):
        """Only pairs within sigma sqrt(ln(1/tol)) of a member fan: exp(-d^2/sigma^2) >= tol."""
        U = np.asarray(U, dtype=float)
        Z = np.asarray(Z, dtype=float).reshape(-1, 2)
        r, c, d2 = _near_pairs(Z, self.fans.positions, self.sigma * np.sqrt(np.log(1.0 / tol)))
        _, dP = _poly(self._coeffs, U)
        vals = np.exp(-d2 / self.sigma ** 2) * (self._members * dP)[c]
        return _sparse_from_pairs(r, c, vals, (len(Z), self.n_fans))

    def to_dict(self):
        out = super().to_dict()
        out['groups'] = list(self.groups)
        return out

    def __repr__(self):
        return (f'FanJets(P_h={np.round(self.thrust_higher, 3).tolist()}, '
                f'P_l={np.round(self.thrust_lower, 3).tolist()}, sigma={self.sigma:.3g} m)')


@register_term
class CentralRing(Term):
    """The central fan's ring: P_c(U_c) (offset + d_c^2 / ring_scale^2) exp(-d_c^2 / sigma^2).

    The paper found that raising the (low-mounted) central fan mostly raises the flow over the
    edge fans; with ``offset`` = 0.1 and ``ring_scale`` = 1 m this is its formula exactly. With
    d in metres that form makes the ring a few hundredths of P_c, so the fitted polynomial must
    be huge; the default ``ring_scale`` of 0.2 m (about the ring's radius) keeps every
    parameter of order one and spans the same family of shapes.
    thrust: P_c coefficients [N]; sigma [m]; offset [-]; ring_scale [m, fixed by default];
    d_c: distance to the central hub [m]. Applies to fans of group ``central`` (none: zero).
    """

    kind = 'central_ring'
    hypers = (Hyper('thrust', 3, POLY_BOUNDS), Hyper('offset', 1, (0.0, 10.0)),
              Hyper('sigma', 1, SIGMA_BOUNDS), Hyper('ring_scale', 1, (0.01, 10.0), fixed=True))

    def __init__(self, fans: FanArray, thrust=(0.0, 1.0, 4.0), offset: float = 0.5,
                 sigma: float = 0.2, ring_scale: float = 0.2, fixed=()):
        self.fans = fans
        self.thrust = np.asarray(thrust, dtype=float)
        self.offset = float(offset)
        self.sigma = float(sigma)
        self.ring_scale = float(ring_scale)
        self._init_hypers(fixed)
        self._check_bounds()
        self._members = fans.group_mask('central')

    def footprint(self, Z):
        d2 = _sq_dist(Z, self.fans.positions)
        return (self.offset + d2 / self.ring_scale ** 2) * np.exp(-d2 / self.sigma ** 2) * self._members

    def _value_and_grad(self, U, Z, jacobian):
        G = self.footprint(Z)
        P, dP = _poly(self.thrust, U)
        return np.sum(G * P, axis=1), (G * dP if jacobian else None)

    def sparse_jacobian(self, U, Z, tol: float = 1e-6):
        """Only pairs where the ring's footprint can exceed tol x its largest value."""
        U = np.asarray(U, dtype=float)
        Z = np.asarray(Z, dtype=float).reshape(-1, 2)
        # (offset + d^2/rs^2) exp(-d^2/s^2) <= (offset + x s^2/rs^2) e^-x with x = d^2/s^2:
        # far enough out that bound is below tol x the peak for x = ln(1/tol) + 8
        reach = self.sigma * np.sqrt(np.log(1.0 / tol) + 8.0)
        centres = self.fans.positions
        r, c, d2 = _near_pairs(Z, centres, reach)
        _, dP = _poly(self.thrust, U)
        keep = self._members[c]
        r, c, d2 = r[keep], c[keep], d2[keep]  # a subset of a grouped, sorted list stays so
        G = (self.offset + d2 / self.ring_scale ** 2) * np.exp(-d2 / self.sigma ** 2)
        return _sparse_from_pairs(r, c, G * dP[c], (len(Z), self.n_fans))

    def __repr__(self):
        return (f'CentralRing(P_c={np.round(self.thrust, 3).tolist()}, offset={self.offset:.3g}, '
                f'sigma={self.sigma:.3g} m)')


def paper_prior(fans: FanArray) -> Term:
    """The paper's prior structure with rough starting values (fit it before use)."""
    jets = FanJets(fans)
    if fans.group_mask('central').any():
        return jets + CentralRing(fans)
    return jets
