"""Candidate effects on the form of chosen fans' footprints: ``FanWidth`` (wider or narrower),
``FanElongation`` (stretched along a direction) and ``FanShape`` (flat-topped or peaked), with
``plate_stretch_share``, how much of a jet's stretch the square plate's average passes on.

Like the other per-fan effects (``fan_effects``), each term states one hypothesis with bounded
parameters whose null value means "no such effect", prints its formula in ``repr`` and is
registered by ``kind``; it wraps the term it changes and selects fans by ``fan`` or ``group``
(``FanWrapper``). Units: positions [m, tunnel frame], forces [N], commands U [fraction 0..1 of
full PWM]; Jacobians are analytic.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import erf

from ..core.errors import ConfigError
from ..core.geometry import FanArray
from .fan_effects import FanWrapper
from .fanwise import PLATE_SIDE, fan_landing, fan_part_batched, fan_width
from .memo import remember
from .terms import Hyper, register_term

__all__ = ['FanWidth', 'FanElongation', 'FanShape', 'plate_stretch_share']


@register_term
class FanWidth(FanWrapper):
    """Hypothesis: a fan's footprint is ``scale`` times as wide as the prior assumes (a fan
    mounted closer to or farther from the honeycomb, another propeller; bounds 0.5..2).

        Phi_j'(U, z) = Phi_j(U, c_j + (z - c_j) / scale_j)      (c_j: where the jet lands)

    The peak force stays; the footprint widens or narrows. Detect: a ring-shaped residual
    around the fan (too low on its flanks when scale > 1)."""

    kind = 'fan_width'
    hypers = (Hyper('scale', 1, (0.5, 2.0)),)

    def __init__(self, fans: FanArray, term, fan=None, group=None, scale=1.0, fixed=()):
        self._init_inner(fans, term)
        self._init_selection(fans, fan, group, fixed)
        self.scale = self._param('scale', scale)
        self._check_bounds()

    def _transform(self, e, j, U, Z, jacobian):
        c, scale = fan_landing(self.inner, j), self.scale[e]
        moved = remember(Z, ('fan_width', c.tobytes(), float(scale)), lambda: c + (Z - c) / scale)
        return fan_part_batched(self.inner, U, moved, j, jacobian)


    def fan_width(self, j):
        def compute():
            w = fan_width(self.inner, j)
            e = self._where.get(int(j))
            return w if (w is None or e is None) else w * self.scale[e]
        return self._memoised(('w', j), compute)

    def __repr__(self):
        return f'FanWidth({self._fans_text(self.scale, lambda s: f"x{s:.3g}")}) o ({self.inner!r})'


def _plate_averaged_gaussian(x, v):
    """(g, g', g''): the mean over [x - 1/2, x + 1/2] of a centred 1-D Gaussian of variance v
    and its first two derivatives in x (lengths in plate sides)."""
    a = np.sqrt(2.0 * v)
    hi, lo = x + 0.5, x - 0.5
    phi_hi = np.exp(-hi ** 2 / (2.0 * v)) / np.sqrt(2.0 * np.pi * v)
    phi_lo = np.exp(-lo ** 2 / (2.0 * v)) / np.sqrt(2.0 * np.pi * v)
    g = (erf(hi / a) - erf(lo / a)) / 2.0
    return g, phi_hi - phi_lo, -(hi * phi_hi - lo * phi_lo) / v


@lru_cache(maxsize=None)
def _stretch_share_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(log rho, kappa along the plate's sides, kappa along its diagonals) on a grid of
    rho = v_jet / plate_side^2 from 0.01 to 100 (see ``plate_stretch_share``)."""
    rhos = np.logspace(-2, 2, 41)
    along, diagonal = [], []
    for rho in rhos:
        x = np.linspace(-1.0, 1.0, 601) * (7.0 * np.sqrt(rho + 1.0 / 12.0))
        g, d1, d2 = _plate_averaged_gaussian(x, rho)
        G, D1, D2 = (np.outer(np.ones_like(x), t) for t in (g, d1, d2))   # as functions of x
        Gy, D1y, D2y = (np.outer(t, np.ones_like(x)) for t in (g, d1, d2))  # of y
        X, Y = np.meshgrid(x, x)
        # a stretch of the jet's covariance by (1 + e, 1 - e) along the sides changes the
        # averaged footprint F by (rho e / 2)(F_xx - F_yy), along a diagonal by rho e F_xy
        # (a Gaussian's derivative in its covariance); the warp of F itself, by the same e,
        # changes it by -(e / 2)(x F_x - y F_y) and -(e / 2)(x F_y + y F_x).
        jet_sides = rho / 2.0 * (D2 * Gy - G * D2y)
        warp_sides = -0.5 * (X * D1 * Gy - Y * G * D1y)
        jet_diag = rho * D1 * D1y
        warp_diag = -0.5 * (X * G * D1y + Y * D1 * Gy)
        along.append(float(np.sum(jet_sides * warp_sides) / np.sum(warp_sides ** 2)))
        diagonal.append(float(np.sum(jet_diag * warp_diag) / np.sum(warp_diag ** 2)))
    return np.log(rhos), np.array(along), np.array(diagonal)


def plate_stretch_share(rho: float) -> tuple[float, float]:
    """(kappa along the plate's sides, kappa along its diagonals): how much of a small
    area-keeping stretch of a Gaussian jet (per-axis variance v_jet = rho plate_side^2) a
    square plate's average passes on, as a multiple of the same stretch of the averaged
    footprint itself (the least-squares match of the two changes). The square passes a stretch
    along its sides and one along its diagonals on differently; both tend to 1 for a jet far
    wider than the plate, and a Gaussian plate of the same variance would pass
    v_jet / (v_jet + plate_side^2 / 12) on in every direction."""
    log_rho, along, diagonal = _stretch_share_table()
    x = np.log(max(float(rho), 1e-2))
    return float(np.interp(x, log_rho, along)), float(np.interp(x, log_rho, diagonal))


@register_term
class FanElongation(FanWrapper):
    """Hypothesis: a fan's jet spreads unevenly (a bent guide vane, a tilted mount): the air
    leaving it is stretched by sqrt(``ratio``) along the direction ``angle`` [rad from +x, CCW]
    and squeezed by 1/sqrt(ratio) across it, keeping its area (ratio 1 = round; bounds 1..4).
    ``ratio`` is the jet's own length-to-width ratio, not that of what the plate sees:

        Phi_j'(U, z) = det(M) Phi_j(U, c_j + M (z - c_j)),   M = R diag(m(ratio), m(1/ratio)) R^T,
        m(q) = (kappa q + 1 - kappa)^(-1/2)

    (c_j: where the jet lands; det(M) keeps the jet's total force). The plate averages the jet
    over its square, which blurs the stretch: kappa is the share of a stretch of the jet that the
    plate passes on, per unit of the same stretch of what it sees (``plate_stretch_share``; M is
    built from the jet's shape with that share, so the formula above is M's along the plate's
    sides; along a diagonal the square passes more on). It is read for a Gaussian jet whose plate
    average has the variance of this fan's footprint in the model (``footprint_variance``: its
    second moment, whatever its form; the plate adds exactly plate_side^2 / 12 per axis to the
    jet's). With a Gaussian plate instead of the square (kappa = v_jet / v_plate in every
    direction, from the Gaussian's width sigma^2 / 2) a jet stretched 1.6 times along a side read
    about 1.55 and one stretched 1.4 times at 34 deg about 1.44 on noise-free sweeps.
    Detect: an elliptical footprint: a four-leaf residual over that fan."""

    kind = 'fan_elongation'
    hypers = (Hyper('ratio', 1, (1.0, 4.0)), Hyper('angle', 1, (-np.pi, np.pi)))

    def __init__(self, fans: FanArray, term, fan=None, group=None, ratio=1.0, angle=0.0,
                 plate_side: float = PLATE_SIDE, fixed=()):
        self._init_inner(fans, term)
        self._init_selection(fans, fan, group, fixed)
        self.ratio = self._param('ratio', ratio)
        self.angle = self._param('angle', angle)
        if not 0 < plate_side < 1:
            raise ConfigError(f'FanElongation.plate_side must be in (0, 1) m; got {plate_side}')
        self.plate_side = float(plate_side)
        self._check_bounds()

    def _structure(self):
        return {**super()._structure(), 'plate_side': self.plate_side}

    def footprint_variance(self, j) -> float:
        """Per-axis variance [m^2] of fan j's footprint in the wrapped model (what the plate
        sees of a lone fan j at command 0.6): its second moment about where the jet lands, on a
        grid of +-4 widths. A Gaussian exp(-d^2/sigma^2) gives sigma^2/2; a flatter top less."""
        def compute():
            sigma = fan_width(self.inner, j) or 0.15
            c = fan_landing(self.inner, j)
            g = np.linspace(-4.0 * sigma, 4.0 * sigma, 41)
            d = np.column_stack([np.repeat(g, len(g)), np.tile(g, len(g))])
            U = np.zeros((len(d), self.n_fans))
            U[:, j] = 0.6
            v, _ = fan_part_batched(self.inner, U, c + d, j, False)
            total = float(np.sum(v))
            if not total > 0:
                return sigma ** 2 / 2.0
            return float(np.sum(v * np.einsum('mk,mk->m', d, d)) / total / 2.0)
        return self._memoised(('variance', j), compute)

    def warp(self, e, j) -> np.ndarray:
        """M (2, 2) for element e and fan j (see the class docstring)."""
        vp = self.footprint_variance(j)
        b = self.plate_side ** 2 / 12.0
        vd = max(vp - b, 0.05 * vp)
        k_sides, k_diagonal = plate_stretch_share(vd / self.plate_side ** 2)
        c2, s2 = np.cos(2.0 * self.angle[e]), np.sin(2.0 * self.angle[e])
        r = self.ratio[e]
        # the jet's shape R diag(r, 1/r) R^T = (1 + t) I + q (c2 [[1, 0], [0, -1]] + s2 [[0, 1], [1, 0]]);
        # the plate passes its part along the sides on by k_sides, along the diagonals by
        # k_diagonal, and its (second-order) widening by their mean
        t, q = (r + 1.0 / r) / 2.0 - 1.0, (r - 1.0 / r) / 2.0
        ks, kd = k_sides * q * c2, k_diagonal * q * s2
        kt = 1.0 + 0.5 * (k_sides + k_diagonal) * t
        seen = np.array([[kt + ks, kd], [kd, kt - ks]])   # what the plate sees, per vp
        w, V = np.linalg.eigh(seen)
        return V @ np.diag(1.0 / np.sqrt(np.maximum(w, 1e-6))) @ V.T

    def _transform(self, e, j, U, Z, jacobian):
        M = self.warp(e, j)
        c = fan_landing(self.inner, j)
        moved = remember(Z, ('fan_elongation', c.tobytes(), M.tobytes()), lambda: c + (Z - c) @ M.T)
        v, jv = fan_part_batched(self.inner, U, moved, j, jacobian)
        k = float(np.linalg.det(M))
        return k * v, (None if jv is None else k * jv)



    def __repr__(self):
        vals = np.column_stack([self.ratio, self.angle])
        text = self._fans_text(vals, lambda v: f'ratio {v[0]:.3g} at {np.degrees(v[1]):.0f} deg')
        return f'FanElongation({text}) o ({self.inner!r})'




@register_term
class FanShape(FanWrapper):
    """Hypothesis: a fan's footprint is flat-topped (or peaked) rather than Gaussian: the
    straightener evens out the jet's core, so the force stays near its peak over the hub and
    falls faster on the shoulder. With d the distance to where the jet lands and sigma its width,

        exp(-d^2 / sigma^2)  becomes  exp(-(d / sigma)^flatness)   (flatness 2 = Gaussian; 1..6)

    done by moving each point radially to c_j + (z - c_j) (d / sigma)^(flatness / 2 - 1).
    Best given per mount group of edge fans. Detect: residuals positive on the shoulder ring of
    every fan of a group and negative further out (flatness > 2)."""

    kind = 'fan_shape'
    hypers = (Hyper('flatness', 1, (1.0, 6.0)),)

    def __init__(self, fans: FanArray, term, fan=None, group=None, flatness=2.0, fixed=()):
        self._init_inner(fans, term)
        self._init_selection(fans, fan, group, fixed)
        self.flatness = self._param('flatness', flatness)
        self._check_bounds()

    def _transform(self, e, j, U, Z, jacobian):
        c = fan_landing(self.inner, j)
        sigma = fan_width(self.inner, j) or 0.15
        flatness = self.flatness[e]

        def move():
            d = Z - c
            r = np.sqrt(np.einsum('mk,mk->m', d, d)) / sigma
            f = np.power(np.maximum(r, 1e-12), 0.5 * flatness - 1.0)
            return c + d * f[:, None]
        moved = remember(Z, ('fan_shape', c.tobytes(), float(sigma), float(flatness)), move)
        return fan_part_batched(self.inner, U, moved, j, jacobian)


    def __repr__(self):
        text = self._fans_text(self.flatness, lambda b: f"exp(-(d/sigma)^{b:.3g})")
        return f'FanShape({text}) o ({self.inner!r})'
