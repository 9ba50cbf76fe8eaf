"""Per-fan candidate effects: wrappers that change chosen fans' jets (``FanGain``, ``FanShift``,
``FanPush``, ``FanWidth``, ``FanElongation``, ``FanCurve``, ``FanShape``).

Each term here states one hypothesis about the tunnel, has bounded parameters whose null value
means "no such effect", prints its formula in ``repr`` and is registered with
``wind_shaper.model.terms.register_term``, so a model file can name it by ``kind``. Units: positions
[m, tunnel frame], forces [N], commands U [fraction 0..1 of full PWM].

Each wraps the term it modifies (``FanWrapper``, a ``Wrapper``, see ``fanwise``) and works on
the fans' parts of it through the fan-resolved protocol: ``FanGain(fans, model, fan='HM2')``
scales one fan's jet. Which fans: ``fan`` (names, one value each), ``group`` (a mount group, one
shared value) or neither (every fan). Jacobians: each term returns dPhi/dU analytically.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import erf

from ..core.errors import ConfigError
from ..core.geometry import FanArray
from .fanwise import (PLATE_SIDE, Wrapper, fan_landing, fan_part_batched, fan_thrust_batched,
                      fan_width, is_fan_sum)
from .memo import remember
from .terms import Hyper, register_term

#: The ``group`` that selects every enabled fan (one value shared by all).
ALL_FANS = 'all'

__all__ = ['ALL_FANS', 'FanWrapper', 'FanGain', 'FanShift', 'FanPush', 'FanWidth', 'FanElongation', 'FanCurve', 'FanShape',
           'plate_stretch_share']


class FanWrapper(Wrapper):
    """A wrapper that changes chosen fans' jets. Which fans: ``fan`` (a name or list of names;
    one parameter value per fan), ``group`` (a mount group, or ``'all'`` for every enabled fan;
    one value shared by its fans), or neither (every fan, one value each). Subclasses declare ``hypers`` with size = values per
    fan (resized here) and implement ``_transform``."""

    def _init_selection(self, fans: FanArray, fan, group, fixed):
        if fan is not None and group is not None:
            raise ConfigError(f'{type(self).__name__}: give fan or group, not both')
        if fan is not None:
            names = (fan,) if isinstance(fan, str) else tuple(fan)
            idx = np.array([fans.index(n) for n in names], dtype=int)
            elem = np.arange(len(idx))
            self.fan, self.group = names, None
        elif group is not None:
            groups = (group,) if isinstance(group, str) else tuple(group)
            idx, elem = [], []
            for e, g in enumerate(groups):
                members = np.flatnonzero(fans.enabled if g == ALL_FANS else fans.group_mask(g))
                if len(members) == 0:
                    raise ConfigError(f'{type(self).__name__}: no fan of group {g!r}; groups are '
                                      f'{sorted(set(fans.groups))}')
                idx += members.tolist()
                elem += [e] * len(members)
            idx, elem = np.array(idx, dtype=int), np.array(elem, dtype=int)
            self.fan, self.group = None, (groups[0] if isinstance(group, str) else groups)
        else:
            idx = np.arange(fans.n_fans)
            elem = np.arange(len(idx))
            self.fan, self.group = None, None
        if len(set(idx.tolist())) != len(idx):
            raise ConfigError(f'{type(self).__name__}: a fan is selected twice ({fan or group})')
        self._idx, self._elem = idx, elem
        self._where = {int(j): int(e) for j, e in zip(idx, elem)}
        n_elem = int(elem.max()) + 1
        fixed = set(fixed or ())
        unknown = fixed - {h.name for h in type(self).hypers}
        if unknown:
            raise ConfigError(f'{type(self).__name__} has no parameters {sorted(unknown)} to fix')
        self.hypers = tuple(Hyper(h.name, h.size * n_elem, h.bounds, h.fixed or h.name in fixed)
                            for h in type(self).hypers)
        self._n_elem = n_elem

    def _param(self, name, default, per=1):
        """A parameter broadcast to (n_elem * per,) from a scalar, per-element list or full."""
        value = np.asarray(default, dtype=float).ravel()
        size = self._n_elem * per
        if value.size == per and size != per:
            value = np.tile(value, self._n_elem)
        if value.size != size:
            raise ConfigError(f'{type(self).__name__}.{name} needs {size} values '
                              f'({self._n_elem} x {per}), got {value.size}')
        return value

    @property
    def label(self):
        if self.fan is not None:
            return f'{self.kind}[{",".join(self.fan)}]'
        if self.group is not None:
            groups = (self.group,) if isinstance(self.group, str) else self.group
            return f'{self.kind}[{",".join(groups)}]'
        return f'{self.kind}[*]'

    def _structure(self):
        group = self.group if (self.group is None or isinstance(self.group, str)) else list(self.group)
        return {'fan': self.fan, 'group': group}

    def to_dict(self):
        out = super().to_dict()
        for key in ('fan', 'group'):
            if out.get(key) is None:
                out.pop(key, None)
        return out

    def _transform(self, e, j, U, Z, jacobian):  # pragma: no cover - abstract
        raise NotImplementedError

    def fan_part(self, U, Z, j, jacobian):
        e = self._where.get(int(j))
        if e is None:
            return fan_part_batched(self.inner, U, Z, j, jacobian)
        return self._transform(e, int(j), U, Z, jacobian)

    def _value_and_grad(self, U, Z, jacobian):
        n = self.n_fans
        if is_fan_sum(self.inner):  # sum the fans' parts: each computed once
            value, jac = np.zeros(len(Z)), (np.zeros((len(Z), n)) if jacobian else None)
            for j in range(n):
                e = self._where.get(j)
                v, jv = (self._transform(e, j, U, Z, jacobian) if e is not None
                         else fan_part_batched(self.inner, U, Z, j, jacobian))
                value += v
                if jacobian:
                    if jv.ndim == 1:
                        jac[:, j] += jv
                    else:
                        jac += jv
            return value, jac
        value, jac = self.inner._value_and_grad(U, Z, jacobian)
        value = value.copy()
        if jacobian:
            jac = jac.copy()
        for j in self._idx:
            v0, j0 = fan_part_batched(self.inner, U, Z, j, jacobian)
            v1, j1 = self._transform(self._where[int(j)], int(j), U, Z, jacobian)
            value += v1 - v0
            if jacobian:
                for jj, sign in ((j1, 1.0), (j0, -1.0)):
                    if jj.ndim == 1:
                        jac[:, j] += sign * jj
                    else:
                        jac += sign * jj
        return value, jac

    def _fans_text(self, values, fmt):
        names = self.fans.names
        if self.group is not None:
            groups = (self.group,) if isinstance(self.group, str) else self.group
            return ', '.join(f'{g} fans: {fmt(values[e])}' for e, g in enumerate(groups))
        return ', '.join(f'{names[j]}: {fmt(values[e])}' for j, e in zip(self._idx, self._elem))


@register_term
class FanGain(FanWrapper):
    """Hypothesis: a fan delivers ``gain`` times the thrust the prior assumes (a worn or chipped
    propeller, a tired ESC or motor, or simply the build spread of fans of one mount group).

        Phi_j'(U, z) = gain_j * Phi_j(U, z)       (gain [-], 1 = as the prior; bounds 0.2..2)

    Phi_j is fan j's part of the wrapped term. Detect: the force over that fan is off by a
    constant factor at every command; its footprint's shape is unchanged."""

    kind = 'fan_gain'
    hypers = (Hyper('gain', 1, (0.2, 2.0)),)

    def __init__(self, fans: FanArray, term, fan=None, group=None, gain=1.0, fixed=()):
        self._init_inner(fans, term)
        self._init_selection(fans, fan, group, fixed)
        self.gain = self._param('gain', gain)
        self._check_bounds()

    def _transform(self, e, j, U, Z, jacobian):
        v, jv = fan_part_batched(self.inner, U, Z, j, jacobian)
        g = self.gain[e]
        return g * v, (None if jv is None else g * jv)

    def fan_thrust(self, U, jacobian):
        T, dT = fan_thrust_batched(self.inner, U, jacobian)
        g = np.ones(self.n_fans)
        g[self._idx] = self.gain[self._elem]
        return T * g, (dT * g if jacobian else None)


    def __repr__(self):
        return f'FanGain({self._fans_text(self.gain, lambda g: f"x{g:.3g}")}) o ({self.inner!r})'


class _MovedJet(FanWrapper):
    """A wrapper that moves chosen fans' jets: ``_move(e, j)`` is the move (2,) [m] of fan j's
    jet (element e); the footprint is evaluated at z - move and lands that far away."""

    def _move(self, e, j) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _transform(self, e, j, U, Z, jacobian):
        move = self._move(e, j)
        moved = remember(Z, ('moved_jet', move.tobytes()), lambda: Z - move)
        return fan_part_batched(self.inner, U, moved, j, jacobian)

    def fan_landing(self, j):
        def compute():
            base = fan_landing(self.inner, j)
            e = self._where.get(int(j))
            return base if e is None else base + self._move(e, int(j))
        return self._memoised(('c', j), compute)


@register_term
class FanShift(_MovedJet):
    """Hypothesis: a fan's jet lands ``shift`` = (dx, dy) [m] away from where the prior puts it
    (a tilted or mis-mounted fan, a bent honeycomb cell above it; bounds +-0.15 m per axis).

        Phi_j'(U, z) = Phi_j(U, z - shift_j)

    Detect: the fan's footprint peak is off its hub: a +/- residual dipole across the hub."""

    kind = 'fan_shift'
    hypers = (Hyper('shift', 2, (-0.15, 0.15)),)

    def __init__(self, fans: FanArray, term, fan=None, group=None, shift=(0.0, 0.0), fixed=()):
        self._init_inner(fans, term)
        self._init_selection(fans, fan, group, fixed)
        self.shift = self._param('shift', shift, per=2)
        self._check_bounds()

    def shift_of(self, e) -> np.ndarray:
        return self.shift[2 * e:2 * e + 2]

    def _move(self, e, j) -> np.ndarray:
        return self.shift_of(e)

    def __repr__(self):
        vals = self.shift.reshape(-1, 2)
        text = self._fans_text(vals, lambda s: f'({100 * s[0]:+.1f}, {100 * s[1]:+.1f}) cm')
        return f'FanShift({text}) o ({self.inner!r})'


@register_term
class FanPush(_MovedJet):
    """Hypothesis: a fan's jet lands ``push`` [m] farther from the tunnel's axis than the prior
    puts it, along the line from the axis through its hub (push < 0: towards the axis; bounds
    +-0.15 m). Jets that cling to the wall or are drawn to the middle move this way, each in its
    own direction, which a shared ``FanShift`` cannot express.

        Phi_j'(U, z) = Phi_j(U, z - push_j * h_j / |h_j|)      (h_j: fan j's hub [m])

    A fan on the axis does not move. With ``group='all'`` every jet moves by one shared push.
    Detect: every off-axis fan's footprint peak moved outwards (or inwards) from its hub."""

    kind = 'fan_push'
    hypers = (Hyper('push', 1, (-0.15, 0.15)),)

    def __init__(self, fans: FanArray, term, fan=None, group=None, push=0.0, fixed=()):
        self._init_inner(fans, term)
        self._init_selection(fans, fan, group, fixed)
        self.push = self._param('push', push)
        hubs = np.asarray(fans.positions, float)
        radius = np.hypot(hubs[:, 0], hubs[:, 1])
        self._outward = np.where(radius[:, None] > 1e-6, hubs / np.maximum(radius, 1e-6)[:, None], 0.0)
        self._check_bounds()

    def _move(self, e, j) -> np.ndarray:
        return self.push[e] * self._outward[j]

    def __repr__(self):
        return f'FanPush({self._fans_text(self.push, lambda p: f"{100 * p:+.1f} cm outwards")}) o ({self.inner!r})'


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
class FanCurve(FanWrapper):
    """Hypothesis: a fan's PWM-to-thrust curve bends more (or less) than the prior's quadratic:

        Phi_j'(U, z) = (1 + bend_j U_j) Phi_j(U, z)        (bend [-], 0 = as the prior; -0.9..3)

    which turns the quadratic P(U) into a cubic (propeller thrust grows faster than U^2 when the
    motor's speed rises faster than linearly with PWM). Best given per mount group
    (``group=['higher', 'lower', 'central']``). Detect: the force over a fan is too low at both
    ends of the command range and too high in the middle (or the reverse)."""

    kind = 'fan_curve'
    hypers = (Hyper('bend', 1, (-0.9, 3.0)),)

    def __init__(self, fans: FanArray, term, fan=None, group=None, bend=0.0, fixed=()):
        self._init_inner(fans, term)
        self._init_selection(fans, fan, group, fixed)
        self.bend = self._param('bend', bend)
        self._check_bounds()

    def _transform(self, e, j, U, Z, jacobian):
        v, jv = fan_part_batched(self.inner, U, Z, j, jacobian)
        b = self.bend[e]
        f = 1.0 + b * U[:, j]
        if not jacobian:
            return v * f, None
        if jv.ndim == 1:
            return v * f, jv * f + b * v
        jac = jv * f[:, None]
        jac[:, j] += b * v
        return v * f, jac

    def fan_thrust(self, U, jacobian):
        T, dT = fan_thrust_batched(self.inner, U, jacobian)
        b = np.zeros(self.n_fans)
        b[self._idx] = self.bend[self._elem]
        f = 1.0 + b[None, :] * U
        return T * f, (dT * f + T * b[None, :] if jacobian else None)


    def __repr__(self):
        return f'FanCurve({self._fans_text(self.bend, lambda b: f"(1 {b:+.3g} U)")}) o ({self.inner!r})'


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
