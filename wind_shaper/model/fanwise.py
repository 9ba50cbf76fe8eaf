"""The fan-resolved protocol, the term-tree helpers and ``Wrapper``, the base of the effect terms
that modify another term (``fan_effects``, ``footprint_effects``, ``flow_effects``).

**Wrappers** modify a term they hold (``term``): ``FanGain(fans, model, fan='HM2')`` scales one
fan's jet, ``Swirl(fans, model)`` turns the whole field about the axis; ``wrap(FanGain, model,
fan='HM2')`` does the same without repeating the fan array. A wrapper's parameters are the
wrapped term's free parameters followed by its own. In a model file a wrapper holds the term it
modifies under ``term:``::

      model:
        kind: fan_gain
        fan: [HM2]
        gain: [0.8]
        term: {kind: sum, terms: [{kind: fan_jets, ...}, {kind: central_ring, ...}]}

Wrappers need to see the prior one fan at a time. That is the *fan-resolved protocol*: the
functions ``fan_part`` (fan j's share of the force and its derivative), ``fan_thrust`` (each
fan's thrust: force over a lone fan's jet [N]), ``fan_width`` (footprint width sigma [m]) and
``fan_landing`` (where fan j's jet lands [m]). ``FanJets``, ``CentralRing``, ``Sum``, ``Product``
(when one factor is a field term) and every wrapper implement it; a user-written term joins
it by defining methods of the same names (see docs/workbench.md). A term outside the protocol
(``Background``, most user terms) is a field term: no fan owns any of it. ``fan_part_batched``
and ``fan_thrust_batched`` are ``fan_part`` and ``fan_thrust`` for commands and points already
batched (U (M, n_fans), Z (M, 2)), without checks: what a wrapper's own methods call.

The tree helpers (``walk``, ``param_slices``, ``find_term``, ``term_label``, ``refix``,
``set_fixed``) visit and re-fix the nodes of a term tree. Units: positions [m, tunnel frame],
forces [N], commands U [fraction 0..1 of full PWM].
"""
from __future__ import annotations

from typing import Callable, Mapping

import copy

import numpy as np

from ..core.errors import ConfigError
from ..core.geometry import FanArray
from .memo import remember
from .prior import CentralRing, FanJets, _poly
from .terms import TERMS, Product, Sum, Term, _batch, term_from_dict

__all__ = ['Wrapper', 'wrap', 'fan_part', 'fan_thrust', 'fan_width', 'fan_landing', 'is_fan_sum',
           'has_fan_parts', 'fan_part_batched', 'fan_thrust_batched', 'walk', 'param_slices', 'find_term',
           'term_label', 'set_fixed', 'refix', 'PLATE_SIDE']

#: Side of the square force plate [m] (the paper's 20 cm plate); terms that average over the
#: plate take ``plate_side`` to override it.
PLATE_SIDE = 0.20


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
    hub, sigma = t.fans.positions[j], t.sigma

    def footprint():
        d = Z - hub
        return np.exp(-np.einsum('mk,mk->m', d, d) / sigma ** 2)
    G = remember(Z, ('fan_jets', hub.tobytes(), float(sigma)), footprint)
    P, dP = _poly(t._coeffs[j], U[:, j])
    return G * P, (G * dP if jacobian else None)


def _ring_part(t: CentralRing, U, Z, j, jacobian):
    if not t._members[j]:
        return _zero_part(len(Z), jacobian)
    hub, offset, ring_scale, sigma = t.fans.positions[j], t.offset, t.ring_scale, t.sigma

    def footprint():
        d = Z - hub
        d2 = np.einsum('mk,mk->m', d, d)
        return (offset + d2 / ring_scale ** 2) * np.exp(-d2 / sigma ** 2)
    G = remember(Z, ('central_ring', hub.tobytes(), float(offset), float(ring_scale), float(sigma)),
                 footprint)
    P, dP = _poly(t.thrust, U[:, j])
    return G * P, (G * dP if jacobian else None)


def _ring_peak(t: CentralRing) -> float:
    """Largest value of the ring footprint (offset + s/rs^2) exp(-s/sigma^2) over s = d^2 >= 0."""
    s = t.sigma ** 2 - t.offset * t.ring_scale ** 2
    if s <= 0:
        return t.offset
    return (t.offset + s / t.ring_scale ** 2) * np.exp(-s / t.sigma ** 2)


def has_fan_parts(term) -> bool:
    """Whether any fan owns part of ``term`` (False for a field term)."""
    if isinstance(term, (FanJets, CentralRing)):
        return True
    if isinstance(term, (Sum, Product)):
        return has_fan_parts(term.k1) or has_fan_parts(term.k2)
    return hasattr(term, 'fan_part')


def fan_part_batched(term, U, Z, j, jacobian):
    """Fan j's share of ``term`` at batched (U, Z): (value (M,), jac). ``fan_part`` without its
    checks: U (M, n_fans) pairs row by row with Z (M, 2) [m], j is an int."""
    if hasattr(term, 'fan_part'):
        return term.fan_part(U, Z, j, jacobian)
    if isinstance(term, FanJets):
        return _jets_part(term, U, Z, j, jacobian)
    if isinstance(term, CentralRing):
        return _ring_part(term, U, Z, j, jacobian)
    if isinstance(term, Sum):
        v1, j1 = fan_part_batched(term.k1, U, Z, j, jacobian)
        v2, j2 = fan_part_batched(term.k2, U, Z, j, jacobian)
        return v1 + v2, (_jadd(j1, j2, j, term.n_fans) if jacobian else None)
    if isinstance(term, Product):
        p1, p2 = has_fan_parts(term.k1), has_fan_parts(term.k2)
        if p1 and p2:
            raise ConfigError(f'no fan owns a share of the product {term!r} of two fan-resolved '
                              f'terms: wrap each factor separately')
        if not (p1 or p2):
            return _zero_part(len(Z), jacobian)
        own, other = (term.k1, term.k2) if p1 else (term.k2, term.k1)
        v, jv = fan_part_batched(own, U, Z, j, jacobian)
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
    return fan_part_batched(term, U, Z, int(j), jacobian)


def fan_thrust_batched(term, U, jacobian):
    """Each fan's thrust (M, n_fans) [N] and dT_j/dU_j (or None) for commands U already of shape
    (M, n_fans): ``fan_thrust`` without its checks."""
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
        t1, d1 = fan_thrust_batched(term.k1, U, jacobian)
        t2, d2 = fan_thrust_batched(term.k2, U, jacobian)
        return t1 + t2, (d1 + d2 if jacobian else None)
    return np.zeros((M, n)), (np.zeros((M, n)) if jacobian else None)


def fan_thrust(term: Term, U, jacobian: bool = False):
    """Each fan's thrust (M, n_fans) [N]: the plate force over a lone fan's jet (the prior's
    P_g(U_j), its peak for the central ring), and with ``jacobian`` dT_j/dU_j (M, n_fans)."""
    U = np.atleast_2d(np.asarray(U, dtype=float))
    if U.shape[1] != term.n_fans:
        raise ConfigError(f'commands for {U.shape[1]} fans given to a model of {term.n_fans}')
    return fan_thrust_batched(term, U, jacobian)


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
            if has_fan_parts(k):
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
        return fan_part_batched(self.inner, U, Z, j, jacobian)

    def fan_thrust(self, U, jacobian):
        return fan_thrust_batched(self.inner, U, jacobian)

    def fan_width(self, j):
        return self._memoised(('w', j), lambda: fan_width(self.inner, j))

    def fan_landing(self, j):
        return self._memoised(('c', j), lambda: fan_landing(self.inner, j))

    def is_fan_sum(self):
        return self._memoised('sum', lambda: is_fan_sum(self.inner))


def wrap(cls, inner: Term, **params) -> Term:
    """``cls(inner.fans, inner, **params)``: wrap a term without repeating its fan array."""
    return cls(inner.fans, inner, **params)
