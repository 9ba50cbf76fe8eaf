"""Whole-flow candidate effects: ``Swirl``, ``JetInteraction``, ``DeadBand`` and ``WallLayer``
(wrappers of the whole field; ``SwirlQuadratic`` and ``JetInteractionPower`` are wider forms of
the first two) and ``Background`` (a field term).

Each term here states one hypothesis about the tunnel, has bounded parameters whose null value
means "no such effect", prints its formula in ``repr`` and is registered with
``wind_shaper.model.terms.register_term``, so a model file can name it by ``kind``. Units: positions
[m, tunnel frame], forces [N], commands U [fraction 0..1 of full PWM].

Two ways of composing with the prior:

* **Field terms** compose with ``+`` and ``*`` like scikit-learn kernels:
  ``model + Background(fans)`` (a uniform updraft).
* **Wrappers** (``Wrapper``, see ``fanwise``) modify a term they hold (``term``):
  ``Swirl(fans, model)`` turns the whole field about the axis.

Jacobians: each term returns dPhi/dU analytically; ``Swirl`` differentiates the wrapped field in
space by central differences (step 1e-5 m).
"""
from __future__ import annotations

import numpy as np
from scipy.special import erf

from ..core.errors import ConfigError
from ..core.geometry import FanArray, neighbour_pairs
from .fanwise import (PLATE_SIDE, Wrapper, _full, fan_landing, fan_part_batched, fan_thrust_batched,
                      fan_width)
from .memo import remember
from .terms import Hyper, Term, register_term

__all__ = ['Swirl', 'SwirlQuadratic', 'JetInteraction', 'JetInteractionPower', 'DeadBand', 'Background',
           'WallLayer']

_EPS_T2 = 1e-4  # [N^2] regularises sqrt(T_i T_j) (and its power) at zero thrust
_DZ = 1e-5      # [m] spatial step of Swirl's central differences


# =============================================================================================
# Wrappers of the whole field
# =============================================================================================

@register_term
class Swirl(Wrapper):
    """Hypothesis: swirl the honeycomb leaves in the flow turns the whole field about the tunnel
    axis when CW and CCW thrusts are unbalanced, by

        b(U) = sum_j s_j T_j(U) / sum_j T_j(U)
        theta(U) = gain * b + curvature * b |b|     [rad, counter-clockwise from above]
        Phi'(U, z) = Phi(U, R(-theta) z)

    with s_j = +1 for CCW and -1 for CW fans and T_j each fan's thrust (``fan_thrust``).
    gain [rad] bounds -1.5..1.5, 0 = no swirl. Here curvature is 0: the angle is proportional
    to the imbalance (``SwirlQuadratic`` frees it). Detect: a residual that is antisymmetric
    about every fan (a rotation) and flips sign with the CW/CCW balance."""

    kind = 'swirl'
    hypers = (Hyper('gain', 1, (-1.5, 1.5)),)
    curvature = 0.0

    def __init__(self, fans: FanArray, term, gain: float = 0.0, fixed=()):
        self._init_inner(fans, term)
        self.gain = float(gain)
        self._init_hypers(fixed)
        self._check_bounds()

    def angle(self, U, jacobian=False):
        """theta (M,) [rad] and, with ``jacobian``, dtheta/dU (M, n_fans)."""
        T, dT = fan_thrust_batched(self.inner, U, jacobian)
        s = self.fans.spin_sign
        S = T.sum(axis=1)
        W = T @ s
        ok = S > 1e-9
        safe = np.where(ok, S, 1.0)
        b = np.where(ok, W / safe, 0.0)
        theta = self.gain * b + self.curvature * b * np.abs(b)
        if not jacobian:
            return theta, None
        slope = self.gain + 2 * self.curvature * np.abs(b)  # dtheta/db
        db = dT * (s[None, :] * safe[:, None] - W[:, None]) / safe[:, None] ** 2
        return theta, np.where(ok[:, None], slope[:, None] * db, 0.0)

    @staticmethod
    def _rotate(Z, theta):
        c, s = np.cos(theta), np.sin(theta)
        return np.column_stack([c * Z[:, 0] + s * Z[:, 1], -s * Z[:, 0] + c * Z[:, 1]])

    @staticmethod
    def _drotate(Z, theta):
        c, s = np.cos(theta), np.sin(theta)
        return np.column_stack([-s * Z[:, 0] + c * Z[:, 1], -c * Z[:, 0] - s * Z[:, 1]])

    def _along(self, fn, Z, Zr, theta):
        """d fn(R(-theta) z) / d theta (M,) by central differences of fn in space."""
        ex, ey = np.array([_DZ, 0.0]), np.array([0.0, _DZ])
        gx = (fn(Zr + ex) - fn(Zr - ex)) / (2 * _DZ)
        gy = (fn(Zr + ey) - fn(Zr - ey)) / (2 * _DZ)
        dZ = self._drotate(Z, theta)
        return gx * dZ[:, 0] + gy * dZ[:, 1]

    def _value_and_grad(self, U, Z, jacobian):
        theta, dtheta = self.angle(U, jacobian)
        Zr = self._rotate(Z, theta)
        value, jac = self.inner._value_and_grad(U, Zr, jacobian)
        if not jacobian:
            return value, None
        along = self._along(lambda P: self.inner._value_and_grad(U, P, False)[0], Z, Zr, theta)
        return value, jac + along[:, None] * dtheta

    def fan_part(self, U, Z, j, jacobian):
        theta, dtheta = self.angle(U, jacobian)
        Zr = self._rotate(Z, theta)
        value, jv = fan_part_batched(self.inner, U, Zr, j, jacobian)
        if not jacobian:
            return value, None
        along = self._along(lambda P: fan_part_batched(self.inner, U, P, j, False)[0], Z, Zr, theta)
        return value, _full(jv, j, self.n_fans) + along[:, None] * dtheta

    def __repr__(self):
        quad = f' + {self.curvature:.3g} rad * b|b|' if self.curvature else ''
        return f'Swirl(theta = {self.gain:.3g} rad * b{quad}, b = (T_ccw - T_cw) / T) o ({self.inner!r})'


@register_term
class SwirlQuadratic(Swirl):
    """Hypothesis: swirl (see ``Swirl``) whose angle is not proportional to the CW/CCW
    imbalance b: theta = gain * b + curvature * b |b| [rad], curvature [rad] bounds -5..5
    (0 = ``Swirl``). The wider form of the swirl family, for a straightener that lets more swirl
    through the more unbalanced the fans are."""

    kind = 'swirl_quadratic'
    hypers = (Hyper('gain', 1, (-1.5, 1.5)), Hyper('curvature', 1, (-5.0, 5.0)))

    def __init__(self, fans: FanArray, term, gain: float = 0.0, curvature: float = 0.0, fixed=()):
        self._init_inner(fans, term)
        self.gain = float(gain)
        self.curvature = float(curvature)
        self._init_hypers(fixed)
        self._check_bounds()


def _plate_gauss(Z, centres, widths, side):
    """Plate average of exp(-|p - m|^2 / w^2) over the square plate of ``side`` [m] centred at
    each point Z (M, 2): (M, P) for centres (P, 2) [m] and widths (P,) [m]. Exact (erf)."""
    w = widths[None, :]
    h = 0.5 * side
    out = np.ones((len(Z), len(centres)))
    for k in range(2):
        d = Z[:, k:k + 1] - centres[None, :, k]
        out *= (erf((d + h) / w) - erf((d - h) / w)) * (np.sqrt(np.pi) * w / (4 * h))
    return out


@register_term
class JetInteraction(Wrapper):
    """Hypothesis: neighbouring jets entrain each other and fill the gap between them:

        Phi'(U, z) = Phi(U, z) + strength * sum_{pairs i~j} sqrt(T_i T_j) B_ij(z)

    B_ij: the plate average of exp(-|p - m_ij|^2 / w_ij^2) around the midpoint m_ij of where the
    two jets land, w_ij = width * the mean of the two jets' own widths (sqrt(sigma^2 - 2 b),
    b = plate_side^2 / 12 the plate's blur). Neighbours: hubs closer than ``reach`` x the
    nearest hub spacing. strength [-] bounds 0..2 (0 = none); width [-] bounds 0.3..3.
    Detect: excess force between fans, growing with both neighbours' thrust.

    ``follows='mean'`` (structural) puts the tunnel's mean thrust T_mean (over the enabled fans)
    in place of each pair's: T_i T_j -> T_mean^2, the same bridges filled by the whole
    tunnel's flow (recirculation, the plenum's pressure) rather than by the two jets. The
    diagnosis checks a jet-interaction finding against that form (the check ``specific`` of
    ``wind_shaper.workbench.checks``)."""

    kind = 'jet_interaction'
    hypers = (Hyper('strength', 1, (0.0, 2.0)), Hyper('width', 1, (0.3, 3.0)))

    def __init__(self, fans: FanArray, term, strength: float = 0.0, width: float = 1.0,
                 reach: float = 1.2, plate_side: float = PLATE_SIDE, follows: str = 'pairs', fixed=()):
        self._init_inner(fans, term)
        self.strength, self.width = float(strength), float(width)
        if not 1.0 <= reach <= 3.0:
            raise ConfigError(f'JetInteraction.reach must be in [1, 3] hub spacings; got {reach}')
        if follows not in ('pairs', 'mean'):
            raise ConfigError(f"JetInteraction.follows must be 'pairs' (each pair's thrusts) or "
                              f"'mean' (the tunnel's mean thrust); got {follows!r}")
        self.reach, self.plate_side, self.follows = float(reach), float(plate_side), follows
        self._init_hypers(fixed)
        self._check_bounds()
        self.pairs = self._pairs()
        self._refresh()

    def _refresh(self):
        b = self.plate_side ** 2 / 12.0
        own = []
        for j in range(self.fans.n_fans):
            s = fan_width(self.inner, j) or 0.15
            own.append(np.sqrt(max(s * s - 2 * b, 0.1 * s * s)))
        own = np.array(own)
        i, k = self.pairs.T if len(self.pairs) else (np.zeros(0, int), np.zeros(0, int))
        self._pair_width = self.width * 0.5 * (own[i] + own[k])
        land = np.array([fan_landing(self.inner, j) for j in range(self.fans.n_fans)])
        self._mid = 0.5 * (land[i] + land[k])

    def _structure(self):
        out = {'reach': self.reach, 'plate_side': self.plate_side}
        if self.follows != 'pairs':
            out['follows'] = self.follows
        return out

    def _pairs(self) -> np.ndarray:
        index = np.flatnonzero(self.fans.enabled)
        pairs = neighbour_pairs(self.fans.positions[index], self.reach)
        return index[pairs] if len(pairs) else np.zeros((0, 2), dtype=int)

    def interaction(self, U, Z, jacobian):
        """The added force (M,) [N] and its Jacobian (M, n_fans)."""
        M = len(Z)
        if len(self.pairs) == 0 or self.strength == 0:
            return np.zeros(M), (np.zeros((M, self.n_fans)) if jacobian else None)
        T, dT = fan_thrust_batched(self.inner, U, jacobian)
        T = np.maximum(T, 0.0)
        i, k = self.pairs[:, 0], self.pairs[:, 1]
        mid, width, side = self._mid, self._pair_width, self.plate_side
        B = remember(Z, ('plate_gauss', mid.tobytes(), width.tobytes(), side),
                     lambda: _plate_gauss(Z, mid, width, side))
        if self.follows == 'mean':
            return self._mean_interaction(T, dT, B, jacobian)
        g, dg = self._pair_thrust(T[:, i] * T[:, k] + _EPS_T2)
        value = self.strength * np.sum(g * B, axis=1)
        if not jacobian:
            return value, None
        jac = np.zeros((M, self.n_fans))
        coef = self.strength * B * dg
        np.add.at(jac.T, i, (coef * T[:, k] * dT[:, i]).T)
        np.add.at(jac.T, k, (coef * T[:, i] * dT[:, k]).T)
        return value, jac

    def _mean_interaction(self, T, dT, B, jacobian):
        """The added force and Jacobian with T_mean^2 for every pair's T_i T_j."""
        enabled = np.flatnonzero(self.fans.enabled)
        mean = T[:, enabled].mean(axis=1)
        g, dg = self._pair_thrust(mean * mean + _EPS_T2)
        bridges = B.sum(axis=1)
        value = self.strength * g * bridges
        if not jacobian:
            return value, None
        jac = np.zeros((len(value), self.n_fans))
        jac[:, enabled] = ((self.strength * bridges * dg * 2.0 * mean / len(enabled))[:, None]
                           * dT[:, enabled])
        return value, jac

    @staticmethod
    def _pair_thrust(x):
        """g(x) [N] of x = T_i T_j + eps [N^2] and dg/dx: here sqrt(x)."""
        root = np.sqrt(x)
        return root, 0.5 / root

    def _value_and_grad(self, U, Z, jacobian):
        v, J = self.inner._value_and_grad(U, Z, jacobian)
        dv, dJ = self.interaction(U, Z, jacobian)
        return v + dv, (J + dJ if jacobian else None)

    def is_fan_sum(self):
        return False

    def __repr__(self):
        thrust = 'T_mean' if self.follows == 'mean' else 'sqrt(T_i T_j)'
        return (f'({self.inner!r}) + JetInteraction({self.strength:.3g} {thrust} over '
                f'{len(self.pairs)} neighbour pairs, width x{self.width:.3g})')


@register_term
class JetInteractionPower(JetInteraction):
    """Hypothesis: neighbouring jets merge and fill the gap between them by a force that grows
    with the two thrusts in a power other than 1/2 (see ``JetInteraction`` for B_ij, the
    neighbours and ``width``):

        Phi'(U, z) = Phi(U, z)
                     + strength * sum_{pairs i~j} T_ref ((T_i T_j + eps) / T_ref^2)^exponent B_ij(z)

    [N], i.e. k (T_i T_j + eps)^exponent B_ij(z) with k = strength T_ref^(1 - 2 exponent)
    [N^(1 - 2 exponent)]: strength is the gap force's share at the reference thrust
    ``thrust_ref`` T_ref [N] (structural, not fitted; default 4 N, about one fan's thrust at half
    command), so strength [-] means what it means in ``JetInteraction`` whatever the exponent,
    and a fit trades strength against exponent less (their correlation on the simulated paper
    rig's sweeps: about -0.8 with T_ref = 4 N, -0.99 with 1 N). eps = 1e-4 N^2.
    strength bounds 0..2 (0 = none, the null value); exponent [-] bounds 0.25..2 (0.5 =
    ``JetInteraction``; 1 for a gap force that grows with the product of the thrusts, below 0.5
    for one that saturates); width [-] bounds 0.3..3. The wider form of the jet-interaction
    family. Detect: excess force between fans that grows faster (or slower) with both
    neighbours' thrust than their geometric mean."""

    kind = 'jet_interaction_power'
    hypers = (Hyper('strength', 1, (0.0, 2.0)), Hyper('width', 1, (0.3, 3.0)),
              Hyper('exponent', 1, (0.25, 2.0)))

    def __init__(self, fans: FanArray, term, strength: float = 0.0, width: float = 1.0,
                 exponent: float = 0.5, reach: float = 1.2, plate_side: float = PLATE_SIDE,
                 thrust_ref: float = 4.0, fixed=()):
        self.exponent = float(exponent)
        if not (np.isfinite(thrust_ref) and thrust_ref > 0):
            raise ConfigError(f'JetInteractionPower.thrust_ref must be a positive thrust [N]; '
                              f'got {thrust_ref}')
        self.thrust_ref = float(thrust_ref)
        super().__init__(fans, term, strength=strength, width=width, reach=reach,
                         plate_side=plate_side, fixed=fixed)

    def _structure(self):
        return {**super()._structure(), 'thrust_ref': self.thrust_ref}

    def _pair_thrust(self, x):
        """T_ref (x / T_ref^2)^exponent [N] of x = T_i T_j + eps [N^2], and its derivative."""
        g = self.thrust_ref * (x / self.thrust_ref ** 2) ** self.exponent
        return g, self.exponent * g / x

    def __repr__(self):
        return (f'({self.inner!r}) + JetInteractionPower({self.strength:.3g} x {self.thrust_ref:g} N '
                f'(T_i T_j / ({self.thrust_ref:g} N)^2)^{self.exponent:.3g} over {len(self.pairs)} '
                f'neighbour pairs, width x{self.width:.3g})')


@register_term
class DeadBand(Wrapper):
    """Hypothesis: the ESCs ignore small commands and saturate: every fan runs at

        U_eff = saturation * clip((U - threshold) / (saturation - threshold), 0, 1)

    so nothing happens below ``threshold`` and nothing more above ``saturation`` (fractions of
    full PWM; threshold bounds 0..0.5, saturation 0.2..1; threshold 0 and saturation 1 = none;
    the span is kept >= 0.05). Detect: the force does not follow a fan's command at its low and
    high ends."""

    kind = 'dead_band'
    hypers = (Hyper('threshold', 1, (0.0, 0.5)), Hyper('saturation', 1, (0.2, 1.0)))

    def __init__(self, fans: FanArray, term, threshold: float = 0.0, saturation: float = 1.0,
                 fixed=()):
        self._init_inner(fans, term)
        self.threshold, self.saturation = float(threshold), float(saturation)
        self._init_hypers(fixed)
        self._check_bounds()

    def effective(self, U):
        """U_eff (M, n) and dU_eff/dU (M, n)."""
        span = max(self.saturation - self.threshold, 0.05)
        x = (U - self.threshold) / span
        inside = (x > 0) & (x < 1)
        return self.saturation * np.clip(x, 0.0, 1.0), np.where(inside, self.saturation / span, 0.0)

    def _value_and_grad(self, U, Z, jacobian):
        Ue, dUe = self.effective(U)
        v, J = self.inner._value_and_grad(Ue, Z, jacobian)
        return v, (J * dUe if jacobian else None)


    def fan_part(self, U, Z, j, jacobian):
        Ue, dUe = self.effective(U)
        v, jv = fan_part_batched(self.inner, Ue, Z, j, jacobian)
        if not jacobian:
            return v, None
        return v, (jv * dUe[:, j] if jv.ndim == 1 else jv * dUe)

    def fan_thrust(self, U, jacobian):
        Ue, dUe = self.effective(U)
        T, dT = fan_thrust_batched(self.inner, Ue, jacobian)
        return T, (dT * dUe if jacobian else None)

    def __repr__(self):
        return (f'DeadBand(U_eff = {self.saturation:.3g} clip((U - {self.threshold:.3g}) / '
                f'{self.saturation - self.threshold:.3g}, 0, 1)) o ({self.inner!r})')


# =============================================================================================
# Field terms (compose with + and *)
# =============================================================================================

@register_term
class Background(Term):
    """Hypothesis: a uniform background updraft (room ventilation, the building's stack effect)
    adds ``force`` [N] to the plate everywhere, whatever the fans do (bounds -1..3 N, 0 = none).
    Compose with ``+``. Detect: a uniform offset, present even with every fan off."""

    kind = 'background'
    hypers = (Hyper('force', 1, (-1.0, 3.0)),)

    def __init__(self, fans: FanArray, force: float = 0.0, fixed=()):
        self.fans = fans
        self.force = float(force)
        self._init_hypers(fixed)
        self._check_bounds()

    def _value_and_grad(self, U, Z, jacobian):
        return (np.full(len(Z), self.force),
                np.zeros((len(Z), self.n_fans)) if jacobian else None)

    def __repr__(self):
        return f'Background({self.force:.3g} N)'



@register_term
class WallLayer(Wrapper):
    """Hypothesis: the flow slows in a viscous boundary layer of ``thickness`` delta [m] at the
    tunnel wall (radius ``wall_radius`` [m]; ``shape`` round, or square for a square duct where
    r = max(|x|, |y|)): the air is multiplied by s(p) = 1 - exp(-(R - r(p)) / delta), and is 0
    outside the wall. The plate feels the air it covers, so the slow-down is averaged over the
    plate (``plate_side`` [m], Gauss-Legendre ``plate_order`` nodes p_k per axis), each node
    weighted by how much air is there, estimated from the wrapped field's radial log-slope g:

        Phi'(U, z) = Phi(U, z) * sum_k w_k e^(g dr_k) s(z + p_k) / sum_k w_k e^(g dr_k)

    (dr_k: how much farther out than z node k lies). A plain product with the mean of s would
    count the air beyond the wall as if it were as strong as at the plate's centre, and fit a
    layer about a third too thin. thickness bounds 0.001..0.3 m. Detect: a deficit that deepens
    towards the wall whichever fan is near."""

    kind = 'wall_layer'
    hypers = (Hyper('thickness', 1, (1e-3, 0.3)),)
    _STEP = 0.01  # [m] radial step of the log-slope

    def __init__(self, fans: FanArray, term, thickness: float = 0.02, wall_radius: float = 0.40,
                 shape: str = 'round', plate_side: float = PLATE_SIDE, plate_order: int = 3,
                 fixed=()):
        self._init_inner(fans, term)
        self.thickness = float(thickness)
        if shape not in ('round', 'square'):
            raise ConfigError(f'WallLayer.shape must be round or square; got {shape!r}')
        if not (wall_radius > 0 and 0 < plate_side < wall_radius and int(plate_order) >= 1):
            raise ConfigError(f'WallLayer needs wall_radius > plate_side > 0 and plate_order >= 1; '
                              f'got {wall_radius}, {plate_side}, {plate_order}')
        self.wall_radius, self.shape = float(wall_radius), shape
        self.plate_side, self.plate_order = float(plate_side), int(plate_order)
        self._init_hypers(fixed)
        self._check_bounds()
        x, w = np.polynomial.legendre.leggauss(self.plate_order)
        xx, yy = np.meshgrid(0.5 * self.plate_side * x, 0.5 * self.plate_side * x)
        self._nodes = np.column_stack([xx.ravel(), yy.ravel()])
        self._weights = (np.outer(w, w) / 4.0).ravel()

    def _structure(self):
        return {'wall_radius': self.wall_radius, 'shape': self.shape, 'plate_side': self.plate_side,
                'plate_order': self.plate_order}

    def _radius(self, P):
        return np.max(np.abs(P), axis=-1) if self.shape == 'square' else np.hypot(P[..., 0], P[..., 1])

    def slow_down(self, P) -> np.ndarray:
        """s at points P (..., 2) [m]: 1 - exp(-(R - r) / delta) inside the wall, 0 outside."""
        gap = self.wall_radius - self._radius(P)
        return np.where(gap > 0, -np.expm1(-np.maximum(gap, 0.0) / self.thickness), 0.0)

    def _geometry(self, Z):
        """Points a step out and in along the radius (M, 2) x 2, and the plate nodes' radial
        offsets dr (M, Q) and radii (M, Q). Remembered for read-only Z (``model.memo``), so a
        fit that calls the term on the same points evaluates the wrapped term on the same
        arrays, whose own geometry is remembered in turn."""
        def compute():
            r = np.hypot(Z[:, 0], Z[:, 1])
            u = Z / np.maximum(r, 1e-9)[:, None]
            u[r < 1e-9] = (1.0, 0.0)
            P = Z[:, None, :] + self._nodes[None]
            rp = self._radius(P)
            return Z + self._STEP * u, Z - self._STEP * u, rp - self._radius(Z)[:, None], rp
        return remember(Z, ('wall_layer', self.shape, self.plate_side, self.plate_order), compute)

    def ratio(self, U, Z, jacobian=False, field=None):
        """The averaged slow-down (M,) and, with ``jacobian``, its derivative (M, n_fans)."""
        Zp, Zm, dr, rp = self._geometry(Z)
        gap = self.wall_radius - rp
        S = np.where(gap > 0, -np.expm1(-np.maximum(gap, 0.0) / self.thickness), 0.0)
        e = self._STEP
        fp, jp = self.inner._value_and_grad(U, Zp, jacobian)
        fm, jm = self.inner._value_and_grad(U, Zm, jacobian)
        f0 = self.inner._value_and_grad(U, Z, False)[0] if field is None else field
        den = np.maximum(np.abs(f0), 1e-3)
        g_raw = (fp - fm) / (2 * e * den)
        g = np.clip(g_raw, -60.0, 60.0)
        W = np.exp(g[:, None] * dr) * self._weights
        sw, sws = W.sum(axis=1), (W * S).sum(axis=1)
        rho = sws / sw
        if not jacobian:
            return rho, None
        # d rho / d g, then d g / dU through the wrapped field (zero where g is clipped)
        drho_dg = (W * S * dr).sum(axis=1) / sw - rho * (W * dr).sum(axis=1) / sw
        _, j0 = self.inner._value_and_grad(U, Z, True)
        sign = np.sign(f0)
        dg = (jp - jm) / (2 * e * den[:, None]) - (g_raw / den * sign)[:, None] * j0 * (np.abs(f0) > 1e-3)[:, None]
        dg = dg * (np.abs(g_raw) < 60.0)[:, None]
        return rho, drho_dg[:, None] * dg

    def _value_and_grad(self, U, Z, jacobian):
        v, J = self.inner._value_and_grad(U, Z, jacobian)
        rho, drho = self.ratio(U, Z, jacobian, field=v)
        return v * rho, (J * rho[:, None] + v[:, None] * drho if jacobian else None)

    def fan_part(self, U, Z, j, jacobian):
        v, jv = fan_part_batched(self.inner, U, Z, j, jacobian)
        rho, drho = self.ratio(U, Z, jacobian)
        if not jacobian:
            return v * rho, None
        return v * rho, _full(jv, j, self.n_fans) * rho[:, None] + v[:, None] * drho

    def is_fan_sum(self):
        return False

    def __repr__(self):
        return (f'({self.inner!r}) * WallLayer(1 - exp(-({self.wall_radius:.3g} m - r) / '
                f'{self.thickness:.3g} m), plate-averaged)')
