"""Candidate effect terms: physical hypotheses the coarse prior leaves out, as model terms.

Each term here states one hypothesis about the tunnel, has bounded parameters whose null value
means "no such effect", prints its formula in ``repr`` and is registered with
``wind_shaper.model.terms.register_term``, so a model file can name it by ``kind``. Units: positions
[m, tunnel frame], forces [N], commands U [fraction 0..1 of full PWM].

Two ways of composing with the prior:

* **Field terms** compose with ``+`` and ``*`` like scikit-learn kernels:
  ``model + Background(fans)`` (a uniform updraft).
* **Wrappers** modify a term they hold (``term``): ``FanGain(fans, model, fan='HM2')`` scales one
  fan's jet, ``Swirl(fans, model)`` turns the whole field about the axis. A wrapper's parameters
  are the wrapped term's free parameters followed by its own. In a model file a wrapper holds the
  term it modifies under ``term:``::

      model:
        kind: fan_gain
        fan: [HM2]
        gain: [0.8]
        term: {kind: sum, terms: [{kind: fan_jets, ...}, {kind: central_ring, ...}]}

Wrappers need to see the prior one fan at a time. That is the *fan-resolved protocol*: the
functions ``fan_part`` (fan j's share of the force and its derivative), ``fan_thrust`` (each
fan's thrust: force over a lone fan's jet [N]), ``fan_width`` (footprint width sigma [m]) and
``fan_landing`` (where fan j's jet lands [m]). ``FanJets``, ``CentralRing``, ``Sum``, ``Product``
(when one factor is a field term) and every wrapper here implement it; a user-written term joins
it by defining methods of the same names (see docs/workbench.md). A term outside the protocol
(``Background``, most user terms) is a field term: no fan owns any of it.

Jacobians: each term returns dPhi/dU analytically; ``Swirl`` differentiates the wrapped field in
space by central differences (step 1e-5 m).
"""
from __future__ import annotations

from typing import Callable, Mapping

import copy

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import erf

from ..core.errors import ConfigError
from ..core.geometry import FanArray
from .terms import (CentralRing, FanJets, Hyper, Product, Sum, Term, _batch, _poly, register_term,
                    term_from_dict)

__all__ = ['Wrapper', 'FanGain', 'FanShift', 'FanWidth', 'FanElongation', 'FanCurve',
           'FanShape', 'Swirl',
           'JetInteraction', 'DeadBand', 'Background', 'WallLayer', 'fan_part', 'fan_thrust',
           'fan_width', 'fan_landing', 'is_fan_sum', 'walk', 'param_slices', 'find_term',
           'term_label', 'set_fixed', 'refix', 'PLATE_SIDE']

#: Side of the square force plate [m] (the paper's 20 cm plate); terms that average over the
#: plate take ``plate_side`` to override it.
PLATE_SIDE = 0.20
_EPS_T2 = 1e-4  # [N^2] regularises sqrt(T_i T_j) at zero thrust
_DZ = 1e-5      # [m] spatial step of Swirl's central differences


# =============================================================================================
# The fan-resolved protocol
# =============================================================================================
# A fan part is (value (M,), jac) where jac is None (not asked), a 1-D (M,) array (only column j
# of dPhi/dU is non-zero) or a 2-D (M, n_fans) array (the full Jacobian of fan j's share).

def _full(jac, j, n):
    if jac is None or jac.ndim == 2:
        return jac
    out = np.zeros((len(jac), n))
    out[:, j] = jac
    return out


def _jadd(a, b, j, n):
    if a is None:
        return b
    if b is None:
        return a
    if a.ndim == 1 and b.ndim == 1:
        return a + b
    return _full(a, j, n) + _full(b, j, n)


def _jscale(jac, factor):
    """Multiply a part's Jacobian by a per-point factor (M,)."""
    if jac is None:
        return None
    return jac * (factor if jac.ndim == 1 else factor[:, None])


def _zero_part(M, jacobian):
    return np.zeros(M), (np.zeros(M) if jacobian else None)


def _jets_part(t: FanJets, U, Z, j, jacobian):
    if not t._members[j]:
        return _zero_part(len(Z), jacobian)
    d = Z - t.fans.positions[j]
    G = np.exp(-np.einsum('mk,mk->m', d, d) / t.sigma ** 2)
    P, dP = _poly(t._coeffs[j], U[:, j])
    return G * P, (G * dP if jacobian else None)


def _ring_part(t: CentralRing, U, Z, j, jacobian):
    if not t._members[j]:
        return _zero_part(len(Z), jacobian)
    d = Z - t.fans.positions[j]
    d2 = np.einsum('mk,mk->m', d, d)
    G = (t.offset + d2 / t.ring_scale ** 2) * np.exp(-d2 / t.sigma ** 2)
    P, dP = _poly(t.thrust, U[:, j])
    return G * P, (G * dP if jacobian else None)


def _ring_peak(t: CentralRing) -> float:
    """Largest value of the ring footprint (offset + s/rs^2) exp(-s/sigma^2) over s = d^2 >= 0."""
    s = t.sigma ** 2 - t.offset * t.ring_scale ** 2
    if s <= 0:
        return t.offset
    return (t.offset + s / t.ring_scale ** 2) * np.exp(-s / t.sigma ** 2)


def _has_parts(term) -> bool:
    """Whether any fan owns part of ``term``."""
    if isinstance(term, (FanJets, CentralRing)):
        return True
    if isinstance(term, (Sum, Product)):
        return _has_parts(term.k1) or _has_parts(term.k2)
    return hasattr(term, 'fan_part')


def _part(term, U, Z, j, jacobian):
    """Fan j's share of ``term`` at batched (U, Z): (value (M,), jac)."""
    if hasattr(term, 'fan_part'):
        return term.fan_part(U, Z, j, jacobian)
    if isinstance(term, FanJets):
        return _jets_part(term, U, Z, j, jacobian)
    if isinstance(term, CentralRing):
        return _ring_part(term, U, Z, j, jacobian)
    if isinstance(term, Sum):
        v1, j1 = _part(term.k1, U, Z, j, jacobian)
        v2, j2 = _part(term.k2, U, Z, j, jacobian)
        return v1 + v2, (_jadd(j1, j2, j, term.n_fans) if jacobian else None)
    if isinstance(term, Product):
        p1, p2 = _has_parts(term.k1), _has_parts(term.k2)
        if p1 and p2:
            raise ConfigError(f'no fan owns a share of the product {term!r} of two fan-resolved '
                              f'terms: wrap each factor separately')
        if not (p1 or p2):
            return _zero_part(len(Z), jacobian)
        own, other = (term.k1, term.k2) if p1 else (term.k2, term.k1)
        v, jv = _part(own, U, Z, j, jacobian)
        w, jw = other._value_and_grad(U, Z, jacobian)
        if not jacobian:
            return v * w, None
        jac = _jscale(jv, w)
        if np.any(jw):
            jac = _full(jac, j, term.n_fans) + v[:, None] * jw
        return v * w, jac
    return _zero_part(len(Z), jacobian)


def fan_part(term: Term, U, Z, j: int, jacobian: bool = False):
    """Fan j's share of ``term``'s force [N] at points Z (M, 2) [m] for commands U, and (with
    ``jacobian``) its derivative dPhi_j/dU: a 1-D (M,) array when only U_j matters, else
    (M, n_fans). Field terms give zeros."""
    U, Z = _batch(U, Z, term.n_fans)
    return _part(term, U, Z, int(j), jacobian)


def _thrust(term, U, jacobian):
    M, n = U.shape
    if hasattr(term, 'fan_thrust'):
        return term.fan_thrust(U, jacobian)
    if isinstance(term, FanJets):
        P, dP = _poly(term._coeffs, U)
        m = term._members
        return P * m, (dP * m if jacobian else None)
    if isinstance(term, CentralRing):
        P, dP = _poly(term.thrust, U)
        scale = _ring_peak(term) * term._members
        return P * scale, (dP * scale if jacobian else None)
    if isinstance(term, (Sum, Product)):
        t1, d1 = _thrust(term.k1, U, jacobian)
        t2, d2 = _thrust(term.k2, U, jacobian)
        return t1 + t2, (d1 + d2 if jacobian else None)
    return np.zeros((M, n)), (np.zeros((M, n)) if jacobian else None)


def fan_thrust(term: Term, U, jacobian: bool = False):
    """Each fan's thrust (M, n_fans) [N]: the plate force over a lone fan's jet (the prior's
    P_g(U_j), its peak for the central ring), and with ``jacobian`` dT_j/dU_j (M, n_fans)."""
    U = np.atleast_2d(np.asarray(U, dtype=float))
    if U.shape[1] != term.n_fans:
        raise ConfigError(f'commands for {U.shape[1]} fans given to a model of {term.n_fans}')
    return _thrust(term, U, jacobian)


def fan_width(term: Term, j: int) -> float | None:
    """Footprint width sigma [m] of fan j's jet in exp(-d^2 / sigma^2), None if no fan j part."""
    if hasattr(term, 'fan_width'):
        return term.fan_width(j)
    if isinstance(term, FanJets):
        return term.sigma if term._members[j] else None
    if isinstance(term, CentralRing):
        return term.sigma if term._members[j] else None
    if isinstance(term, (Sum, Product)):
        w = fan_width(term.k1, j)
        return w if w is not None else fan_width(term.k2, j)
    return None


def fan_landing(term: Term, j: int) -> np.ndarray:
    """Where fan j's jet lands (2,) [m, tunnel frame]: its hub unless a wrapper moved it."""
    if hasattr(term, 'fan_landing'):
        return term.fan_landing(j)
    if isinstance(term, (Sum, Product)):
        for k in (term.k1, term.k2):
            if _has_parts(k):
                return fan_landing(k, j)
    return term.fans.positions[j].copy()


def is_fan_sum(term: Term) -> bool:
    """True if ``term`` is exactly the sum of its fans' parts (no field term anywhere)."""
    if hasattr(term, 'is_fan_sum'):
        return term.is_fan_sum()
    if isinstance(term, (FanJets, CentralRing)):
        return True
    if isinstance(term, Sum):
        return is_fan_sum(term.k1) and is_fan_sum(term.k2)
    return False


# =============================================================================================
# Tree helpers
# =============================================================================================

def term_label(term: Term) -> str:
    """A term's label: ``kind`` plus, for per-fan wrappers, which fans (``fan_gain[HM2]``)."""
    return getattr(term, 'label', None) or term.kind or type(term).__name__


def walk(term: Term):
    """Every node of a term tree, depth first, parents before children."""
    yield term
    if isinstance(term, (Sum, Product)):
        yield from walk(term.k1)
        yield from walk(term.k2)
    elif isinstance(term, Wrapper):
        yield from walk(term.inner)
    elif hasattr(term, 'children'):
        for child in term.children():
            yield from walk(child)


def param_slices(term: Term, start: int = 0):
    """(node, slice into ``term.theta`` of the node's OWN free parameters) for every node."""
    if isinstance(term, (Sum, Product)):
        out = param_slices(term.k1, start)
        out += param_slices(term.k2, start + len(term.k1.theta))
        return [(term, slice(start, start))] + out
    if isinstance(term, Wrapper):
        n_in = len(term.inner.theta)
        return ([(term, slice(start + n_in, start + len(term.theta)))]
                + param_slices(term.inner, start))
    if hasattr(term, 'children'):  # a non-standard container without its own parameters
        out, pos = [(term, slice(start, start))], start
        for child in term.children():
            out += param_slices(child, pos)
            pos += len(child.theta)
        return out
    return [(term, slice(start, start + len(term.theta)))]


def find_term(term: Term, label: str):
    """The first node whose ``term_label`` is ``label`` (None if absent)."""
    for node in walk(term):
        if term_label(node) == label:
            return node
    return None


def refix(term: Term, choose: Callable[[dict, type], list | None]) -> Term:
    """A copy of ``term`` whose nodes' fixed parameters are ``choose(spec, cls)``: the names to
    fix for the node with model-file entry ``spec`` and term class ``cls``, or None to leave the
    node as it is. Goes through the model-file form, so it works for every registered term."""
    from .terms import TERMS

    def visit(spec):
        spec = dict(spec)
        if spec.get('kind') in ('sum', 'product'):
            spec['terms'] = [visit(t) for t in spec['terms']]
            return spec
        if isinstance(spec.get('term'), Mapping):
            spec['term'] = visit(spec['term'])
        names = choose(spec, TERMS[spec['kind']])
        if names is not None:
            spec['fixed'] = list(names)
        return spec

    return term_from_dict(visit(term.to_dict()), term.fans)


def set_fixed(term: Term, fixed: bool, where: Callable[[dict], bool] = lambda spec: True) -> Term:
    """A copy of ``term`` with every parameter of the nodes selected by ``where`` (a predicate
    on the node's ``to_dict`` entry, e.g. ``lambda s: s['kind'] == 'fan_gain'``) fixed (or
    freed, back to the class's own fixed parameters)."""
    def choose(spec, cls):
        if not where(spec):
            return None
        return [h.name for h in cls.hypers if fixed or h.fixed]
    return refix(term, choose)


# =============================================================================================
# Wrappers
# =============================================================================================

def _own_theta(term) -> np.ndarray:
    parts = [np.atleast_1d(np.asarray(getattr(term, h.name), dtype=float)) for h in term._free()]
    return np.concatenate(parts) if parts else np.zeros(0)


def _own_names(term) -> list[str]:
    names = []
    for h in term._free():
        names += [h.name] if h.size == 1 else [f'{h.name}[{i}]' for i in range(h.size)]
    return names


def _own_bounds(term) -> np.ndarray:
    rows = [h.element_bounds() for h in term._free()]
    return np.vstack(rows) if rows else np.zeros((0, 2))


class Wrapper(Term):
    """Base class of terms that modify another term, ``inner`` (given as ``term``: a Term or
    its model-file mapping). Parameters: the inner term's free parameters, then the wrapper's
    own (named ``<label>.<name>`` in ``theta_names``). ``get_params`` and ``fixed_names`` are
    the wrapper's own; ``to_dict`` nests the inner term under ``term``."""

    def _init_inner(self, fans: FanArray, term):
        inner = term if isinstance(term, Term) else term_from_dict(term, fans)
        if inner.fans != fans:
            raise ConfigError(f'{type(self).__name__}: the wrapped term is for another fan array')
        self.fans, self.inner = fans, inner

    # structural (non-fitted) constructor arguments; subclasses extend
    def _structure(self) -> dict:
        return {}

    @property
    def theta(self):
        return np.concatenate([self.inner.theta, _own_theta(self)])

    @property
    def theta_names(self):
        return self.inner.theta_names + [f'{term_label(self)}.{n}' for n in _own_names(self)]

    @property
    def bounds(self):
        return np.vstack([self.inner.bounds, _own_bounds(self)])

    def with_theta(self, theta):
        theta = np.asarray(theta, dtype=float)
        n_in = self._memoised('n_in', lambda: len(self.inner.theta))
        n_all = self._memoised('n_all', lambda: len(self.theta))
        if theta.shape != (n_all,):
            raise ConfigError(f'{type(self).__name__} has {n_all} free parameters, got {theta.shape}')
        # A shallow copy with the new values: the bounds are the fitter's business here, and
        # skipping __init__'s checks keeps fits fast. Derived state is rebuilt by _refresh.
        new = copy.copy(self)
        new.inner = self.inner.with_theta(theta[:n_in])
        i = n_in
        for h in self._free():
            chunk = theta[i:i + h.size]
            setattr(new, h.name, float(chunk[0]) if h.size == 1 and np.ndim(getattr(self, h.name)) == 0
                    else chunk.copy())
            i += h.size
        new._memo = {}
        new._refresh()
        return new

    def _refresh(self):
        """Rebuild state derived from the parameters or the inner term (after with_theta)."""

    def _memoised(self, key, fn):
        memo = self.__dict__.setdefault('_memo', {})
        if key not in memo:
            memo[key] = fn()
        return memo[key]

    def clone(self, **overrides):
        term = overrides.pop('term', self.inner)
        params = self.get_params()
        params.update(overrides)
        return type(self)(self.fans, term, **self._structure(), **params, fixed=self.fixed_names)

    def to_dict(self):
        out = {'kind': self.kind}
        for key, value in self._structure().items():
            out[key] = list(value) if isinstance(value, tuple) else value
        for name, value in self.get_params().items():
            out[name] = np.asarray(value).tolist()
        if self.fixed_names:
            out['fixed'] = list(self.fixed_names)
        out['term'] = self.inner.to_dict()
        return out

    # the protocol, by default passed through to the inner term
    def fan_part(self, U, Z, j, jacobian):
        return _part(self.inner, U, Z, j, jacobian)

    def fan_thrust(self, U, jacobian):
        return _thrust(self.inner, U, jacobian)

    def fan_width(self, j):
        return self._memoised(('w', j), lambda: fan_width(self.inner, j))

    def fan_landing(self, j):
        return self._memoised(('c', j), lambda: fan_landing(self.inner, j))

    def is_fan_sum(self):
        return self._memoised('sum', lambda: is_fan_sum(self.inner))


class _FanWrapper(Wrapper):
    """A wrapper that changes chosen fans' jets. Which fans: ``fan`` (a name or list of names;
    one parameter value per fan), ``group`` (a mount group; one value shared by its fans), or
    neither (every fan, one value each). Subclasses declare ``hypers`` with size = values per
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
                members = np.flatnonzero(fans.group_mask(g))
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
            return _part(self.inner, U, Z, j, jacobian)
        return self._transform(e, int(j), U, Z, jacobian)

    def _value_and_grad(self, U, Z, jacobian):
        n = self.n_fans
        if is_fan_sum(self.inner):  # sum the fans' parts: each computed once
            value, jac = np.zeros(len(Z)), (np.zeros((len(Z), n)) if jacobian else None)
            for j in range(n):
                e = self._where.get(j)
                v, jv = (self._transform(e, j, U, Z, jacobian) if e is not None
                         else _part(self.inner, U, Z, j, jacobian))
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
            v0, j0 = _part(self.inner, U, Z, j, jacobian)
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
class FanGain(_FanWrapper):
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
        v, jv = _part(self.inner, U, Z, j, jacobian)
        g = self.gain[e]
        return g * v, (None if jv is None else g * jv)

    def fan_thrust(self, U, jacobian):
        T, dT = _thrust(self.inner, U, jacobian)
        g = np.ones(self.n_fans)
        g[self._idx] = self.gain[self._elem]
        return T * g, (dT * g if jacobian else None)


    def __repr__(self):
        return f'FanGain({self._fans_text(self.gain, lambda g: f"x{g:.3g}")}) o ({self.inner!r})'


@register_term
class FanShift(_FanWrapper):
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

    def _transform(self, e, j, U, Z, jacobian):
        return _part(self.inner, U, Z - self.shift_of(e), j, jacobian)


    def fan_landing(self, j):
        def compute():
            base = fan_landing(self.inner, j)
            e = self._where.get(int(j))
            return base if e is None else base + self.shift_of(e)
        return self._memoised(('c', j), compute)

    def __repr__(self):
        vals = self.shift.reshape(-1, 2)
        text = self._fans_text(vals, lambda s: f'({100 * s[0]:+.1f}, {100 * s[1]:+.1f}) cm')
        return f'FanShift({text}) o ({self.inner!r})'


@register_term
class FanWidth(_FanWrapper):
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
        c = fan_landing(self.inner, j)
        return _part(self.inner, U, c + (Z - c) / self.scale[e], j, jacobian)


    def fan_width(self, j):
        def compute():
            w = fan_width(self.inner, j)
            e = self._where.get(int(j))
            return w if (w is None or e is None) else w * self.scale[e]
        return self._memoised(('w', j), compute)

    def __repr__(self):
        return f'FanWidth({self._fans_text(self.scale, lambda s: f"x{s:.3g}")}) o ({self.inner!r})'


@register_term
class FanElongation(_FanWrapper):
    """Hypothesis: a fan's jet spreads unevenly (a bent guide vane, a tilted mount): the air
    leaving it is stretched by sqrt(``ratio``) along the direction ``angle`` [rad from +x, CCW]
    and squeezed by 1/sqrt(ratio) across it, keeping its area (ratio 1 = round; bounds 1..4).

    The stretch acts on the air before the plate averages it: with the jet's local variance
    v_d = sigma^2/2 - b per axis (b = plate_side^2 / 12, the plate's own blur), the plate sees
    the covariance S' = v_d R diag(ratio, 1/ratio) R^T + b I instead of S = sigma^2/2 I, so

        Phi_j'(U, z) = det(M) Phi_j(U, c_j + M (z - c_j)),   M = (S S'^-1)^(1/2)

    (c_j: where the jet lands), which keeps the jet's total force. ``ratio`` is thus the ratio of the jet itself, not of
    what the plate sees. Detect: an elliptical footprint: a four-leaf residual over that fan."""

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

    def warp(self, e, j) -> np.ndarray:
        """M (2, 2) for element e and fan j (see the class docstring)."""
        sigma = fan_width(self.inner, j) or 0.15
        b = self.plate_side ** 2 / 12.0
        vp = sigma ** 2 / 2.0
        vd = max(vp - b, 0.05 * vp)
        c, s = np.cos(self.angle[e]), np.sin(self.angle[e])
        R = np.array([[c, -s], [s, c]])
        r = self.ratio[e]
        lam = vp / (vd * np.array([r, 1.0 / r]) + (vp - vd))  # eigenvalues of S S'^-1
        return R @ np.diag(np.sqrt(lam)) @ R.T

    def _transform(self, e, j, U, Z, jacobian):
        M = self.warp(e, j)
        c = fan_landing(self.inner, j)
        v, jv = _part(self.inner, U, c + (Z - c) @ M.T, j, jacobian)
        k = float(np.linalg.det(M))
        return k * v, (None if jv is None else k * jv)



    def __repr__(self):
        vals = np.column_stack([self.ratio, self.angle])
        text = self._fans_text(vals, lambda v: f'ratio {v[0]:.3g} at {np.degrees(v[1]):.0f} deg')
        return f'FanElongation({text}) o ({self.inner!r})'


@register_term
class FanCurve(_FanWrapper):
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
        v, jv = _part(self.inner, U, Z, j, jacobian)
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
        T, dT = _thrust(self.inner, U, jacobian)
        b = np.zeros(self.n_fans)
        b[self._idx] = self.bend[self._elem]
        f = 1.0 + b[None, :] * U
        return T * f, (dT * f + T * b[None, :] if jacobian else None)


    def __repr__(self):
        return f'FanCurve({self._fans_text(self.bend, lambda b: f"(1 {b:+.3g} U)")}) o ({self.inner!r})'


@register_term
class FanShape(_FanWrapper):
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
        d = Z - c
        r = np.sqrt(np.einsum('mk,mk->m', d, d)) / sigma
        f = np.power(np.maximum(r, 1e-12), 0.5 * self.flatness[e] - 1.0)
        return _part(self.inner, U, c + d * f[:, None], j, jacobian)


    def __repr__(self):
        text = self._fans_text(self.flatness, lambda b: f"exp(-(d/sigma)^{b:.3g})")
        return f'FanShape({text}) o ({self.inner!r})'


@register_term
class Swirl(Wrapper):
    """Hypothesis: swirl the honeycomb leaves in the flow turns the whole field about the tunnel
    axis when CW and CCW thrusts are unbalanced, by

        theta(U) = gain * sum_j s_j T_j(U) / sum_j T_j(U)     [rad, counter-clockwise from above]
        Phi'(U, z) = Phi(U, R(-theta) z)

    with s_j = +1 for CCW and -1 for CW fans and T_j each fan's thrust (``fan_thrust``).
    gain [rad] bounds -1.5..1.5, 0 = no swirl. Detect: a residual that is antisymmetric about
    every fan (a rotation) and flips sign with the CW/CCW balance."""

    kind = 'swirl'
    hypers = (Hyper('gain', 1, (-1.5, 1.5)),)

    def __init__(self, fans: FanArray, term, gain: float = 0.0, fixed=()):
        self._init_inner(fans, term)
        self.gain = float(gain)
        self._init_hypers(fixed)
        self._check_bounds()

    def angle(self, U, jacobian=False):
        """theta (M,) [rad] and, with ``jacobian``, dtheta/dU (M, n_fans)."""
        T, dT = _thrust(self.inner, U, jacobian)
        s = self.fans.spin_sign
        S = T.sum(axis=1)
        W = T @ s
        ok = S > 1e-9
        safe = np.where(ok, S, 1.0)
        theta = np.where(ok, self.gain * W / safe, 0.0)
        if not jacobian:
            return theta, None
        dtheta = self.gain * dT * (s[None, :] * safe[:, None] - W[:, None]) / safe[:, None] ** 2
        return theta, np.where(ok[:, None], dtheta, 0.0)

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
        value, jv = _part(self.inner, U, Zr, j, jacobian)
        if not jacobian:
            return value, None
        along = self._along(lambda P: _part(self.inner, U, P, j, False)[0], Z, Zr, theta)
        return value, _full(jv, j, self.n_fans) + along[:, None] * dtheta

    def __repr__(self):
        return f'Swirl(theta = {self.gain:.3g} rad * (T_ccw - T_cw) / T) o ({self.inner!r})'


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
    Detect: excess force between fans, growing with both neighbours' thrust."""

    kind = 'jet_interaction'
    hypers = (Hyper('strength', 1, (0.0, 2.0)), Hyper('width', 1, (0.3, 3.0)))

    def __init__(self, fans: FanArray, term, strength: float = 0.0, width: float = 1.0,
                 reach: float = 1.2, plate_side: float = PLATE_SIDE, fixed=()):
        self._init_inner(fans, term)
        self.strength, self.width = float(strength), float(width)
        if not 1.0 <= reach <= 3.0:
            raise ConfigError(f'JetInteraction.reach must be in [1, 3] hub spacings; got {reach}')
        self.reach, self.plate_side = float(reach), float(plate_side)
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
        return {'reach': self.reach, 'plate_side': self.plate_side}

    def _pairs(self) -> np.ndarray:
        hubs = self.fans.positions[self.fans.enabled]
        index = np.flatnonzero(self.fans.enabled)
        if len(hubs) < 2:
            return np.zeros((0, 2), dtype=int)
        tree = cKDTree(hubs)
        dist, _ = tree.query(hubs, k=2)
        spacing = float(np.min(dist[:, 1]))
        if spacing <= 0:
            return np.zeros((0, 2), dtype=int)
        pairs = tree.query_pairs(self.reach * spacing * (1 + 1e-9), output_type='ndarray')
        return index[pairs] if len(pairs) else np.zeros((0, 2), dtype=int)

    def interaction(self, U, Z, jacobian):
        """The added force (M,) [N] and its Jacobian (M, n_fans)."""
        M = len(Z)
        if len(self.pairs) == 0 or self.strength == 0:
            return np.zeros(M), (np.zeros((M, self.n_fans)) if jacobian else None)
        T, dT = _thrust(self.inner, U, jacobian)
        T = np.maximum(T, 0.0)
        i, k = self.pairs[:, 0], self.pairs[:, 1]
        root = np.sqrt(T[:, i] * T[:, k] + _EPS_T2)
        B = _plate_gauss(Z, self._mid, self._pair_width, self.plate_side)
        value = self.strength * np.sum(root * B, axis=1)
        if not jacobian:
            return value, None
        jac = np.zeros((M, self.n_fans))
        coef = self.strength * B / (2 * root)
        np.add.at(jac.T, i, (coef * T[:, k] * dT[:, i]).T)
        np.add.at(jac.T, k, (coef * T[:, i] * dT[:, k]).T)
        return value, jac

    def _value_and_grad(self, U, Z, jacobian):
        v, J = self.inner._value_and_grad(U, Z, jacobian)
        dv, dJ = self.interaction(U, Z, jacobian)
        return v + dv, (J + dJ if jacobian else None)

    def is_fan_sum(self):
        return False

    def __repr__(self):
        return (f'({self.inner!r}) + JetInteraction({self.strength:.3g} sqrt(T_i T_j) over '
                f'{len(self.pairs)} neighbour pairs, width x{self.width:.3g})')


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
        v, jv = _part(self.inner, Ue, Z, j, jacobian)
        if not jacobian:
            return v, None
        return v, (jv * dUe[:, j] if jv.ndim == 1 else jv * dUe)

    def fan_thrust(self, U, jacobian):
        Ue, dUe = self.effective(U)
        T, dT = _thrust(self.inner, Ue, jacobian)
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


_WALL_CACHE: dict = {}


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
        offsets dr (M, Q) and radii (M, Q). Kept for the last few Z arrays, so a fit that calls
        the term on the same points again evaluates the wrapped term on the same arrays."""
        key = (Z.__array_interface__['data'][0], Z.shape, Z.strides, self.shape, self.plate_side,
               self.plate_order)
        hit = _WALL_CACHE.get(key)
        if hit is not None:
            return hit[1]
        r = np.hypot(Z[:, 0], Z[:, 1])
        u = Z / np.maximum(r, 1e-9)[:, None]
        u[r < 1e-9] = (1.0, 0.0)
        P = Z[:, None, :] + self._nodes[None]
        rp = self._radius(P)
        out = (Z + self._STEP * u, Z - self._STEP * u, rp - self._radius(Z)[:, None], rp)
        if len(_WALL_CACHE) >= 8:
            _WALL_CACHE.clear()
        _WALL_CACHE[key] = (Z, out)
        return out

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
        v, jv = _part(self.inner, U, Z, j, jacobian)
        rho, drho = self.ratio(U, Z, jacobian)
        if not jacobian:
            return v * rho, None
        return v * rho, _full(jv, j, self.n_fans) * rho[:, None] + v[:, None] * drho

    def is_fan_sum(self):
        return False

    def __repr__(self):
        return (f'({self.inner!r}) * WallLayer(1 - exp(-({self.wall_radius:.3g} m - r) / '
                f'{self.thickness:.3g} m), plate-averaged)')


def wrap(cls, inner: Term, **params) -> Term:
    """``cls(inner.fans, inner, **params)``: wrap a term without repeating its fan array."""
    return cls(inner.fans, inner, **params)


__all__.append('wrap')
