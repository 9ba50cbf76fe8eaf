"""Per-fan candidate effects: wrappers that change chosen fans' jets (``FanGain``, ``FanShift``,
``FanPush``, ``FanCurve``; the footprint's form: ``footprint_effects``).

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

import numpy as np

from ..core.errors import ConfigError
from ..core.geometry import FanArray
from .fanwise import Wrapper, fan_landing, fan_part_batched, fan_thrust_batched, is_fan_sum
from .memo import remember
from .prior import paper_prior
from .terms import Hyper, Term, register_term

#: The ``group`` that selects every enabled fan (one value shared by all).
ALL_FANS = 'all'

__all__ = ['ALL_FANS', 'FanWrapper', 'FanGain', 'FanShift', 'FanPush', 'FanCurve', 'sweep_prior']


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


def sweep_prior(fans: FanArray) -> Term:
    """The paper's prior (``paper_prior``) with every enabled fan's jet moved by one shared
    shift (``FanShift`` of the group ``all``): where the whole field lands, which a draft across
    the tunnel or the motion capture's origin off the tunnel's axis displaces. The paper's prior
    puts every jet on its fan's hub, so a field displaced as a whole bends its fitted gains and
    widths instead, and the shaping loop's per-fan fit, which moves each jet by a few centimetres
    at most, cannot take that back. `calibrate --data` fits it beside the paper's prior and keeps
    the one that predicts the held-out sweeps better
    (``workbench.calibrate.calibrate_default_prior``)."""
    return FanShift(fans, paper_prior(fans), group=ALL_FANS)


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
