"""Composable model terms: the machinery the prior (``prior``) and the effect terms are built of.

A term maps fan commands U [fraction 0..1, one per fan] and plate-centre points z [m, tunnel
frame] to the vertical force on the plate [N], and gives its Jacobian dPhi/dU [N per unit
PWM]. Terms add and multiply like scikit-learn kernels (``jets + ring``, ``jets * wall``), keep
their parameters only in ``__init__``, declare each parameter's bounds (or fix it) and print
their formula in ``repr``. ``theta`` is the vector of free parameters, which is what a fit moves.
Each kind registers itself in ``TERMS`` with ``register_term`` so a model file can name it;
``term_from_dict`` builds a term (tree) back from its ``to_dict`` form.

Evaluation is batched: ``U`` is either one command vector (n_fans,) applied at every point,
or one row per point (M, n_fans) paired with ``Z`` (M, 2).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Mapping

import numpy as np

from ..core.errors import ConfigError, ModelFileError
from ..core.limits import excerpt
from ..core.geometry import FanArray
from .plugins import HOW_TO_LOAD, load_plugins


@dataclass(frozen=True)
class Hyper:
    """Declaration of a term parameter: name, element count, bounds, fixed or free.

    bounds: one (low, high) pair for every element, or one pair per element."""

    name: str
    size: int = 1
    bounds: tuple = (-np.inf, np.inf)
    fixed: bool = False

    def element_bounds(self) -> np.ndarray:
        """(size, 2) bounds of each element."""
        b = np.asarray(self.bounds, dtype=float)
        return np.broadcast_to(b, (self.size, 2)) if b.ndim == 1 else b.reshape(self.size, 2)


def _batch(U, Z, n_fans):
    """Broadcast commands to one row per point. Returns U (M, n_fans), Z (M, 2)."""
    Z = np.asarray(Z, dtype=float)
    if Z.ndim != 2 or Z.shape[1] != 2:  # keep (M, 2) arrays as they are: model.memo knows them
        Z = Z.reshape(-1, 2)
    U = np.asarray(U, dtype=float)
    if U.ndim == 1:
        if U.shape[0] != n_fans:
            raise ConfigError(f'command vector has {U.shape[0]} entries for {n_fans} fans')
        U = np.broadcast_to(U, (len(Z), n_fans))
    elif U.shape != (len(Z), n_fans):
        raise ConfigError(f'commands {U.shape} do not pair with points {Z.shape} for {n_fans} fans')
    return U, Z


#: (point, fan) pairs evaluated at once by the dense fallback of ``Term.sparse_jacobian``.
_PAIRS_PER_BLOCK = 1 << 21


class Term:
    """Base class of model terms. Subclasses set ``hypers`` and implement ``_value_and_grad``."""

    hypers: ClassVar[tuple[Hyper, ...]] = ()
    kind: ClassVar[str] = ''

    # -- evaluation ----------------------------------------------------------------------------
    def __call__(self, U, Z) -> np.ndarray:
        """Force on the plate [N] at points Z (M, 2) [m] for commands U; shape (M,)."""
        return self.value_and_jacobian(U, Z, jacobian=False)[0]

    def jacobian(self, U, Z) -> np.ndarray:
        """dPhi/dU at (U, Z): (M, n_fans) [N per unit PWM]."""
        return self.value_and_jacobian(U, Z, jacobian=True)[1]

    def value_and_jacobian(self, U, Z, jacobian=True):
        U, Z = _batch(U, Z, self.n_fans)
        return self._value_and_grad(U, Z, jacobian)

    def sparse_jacobian(self, U, Z, tol: float = 1e-6):
        """dPhi/dU at one command vector U (n_fans,) and points Z (M, 2) [m] as a
        ``scipy.sparse`` CSC matrix (M, n_fans) [N per unit PWM], for large fan walls.

        Entries below ``tol`` x the largest are dropped. This default evaluates dense blocks of
        points (memory bounded by the block); ``FanJets`` and ``CentralRing`` evaluate only the
        (point, fan) pairs within their footprint's reach."""
        import scipy.sparse as sp
        Z = np.asarray(Z, dtype=float).reshape(-1, 2)
        step = max(1, _PAIRS_PER_BLOCK // self.n_fans)
        rows, cols, vals = [], [], []
        for lo in range(0, len(Z), step):
            J = self.jacobian(U, Z[lo:lo + step])
            cut = tol * float(np.max(np.abs(J))) if J.size else 0.0
            r, c = np.nonzero(np.abs(J) > cut)
            rows.append(r + lo)
            cols.append(c)
            vals.append(J[r, c])
        return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(len(Z), self.n_fans))

    def _value_and_grad(self, U, Z, jacobian):  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def n_fans(self) -> int:
        return self.fans.n_fans

    # -- parameters ----------------------------------------------------------------------------
    def get_params(self) -> dict:
        """Parameter name -> value (floats or 1-D arrays), including fixed ones."""
        return {h.name: getattr(self, h.name) for h in self.hypers}

    def _free(self):
        return [h for h in self.hypers if not h.fixed]

    @property
    def theta(self) -> np.ndarray:
        """Free parameters, concatenated in declaration order."""
        parts = [np.atleast_1d(np.asarray(getattr(self, h.name), dtype=float)) for h in self._free()]
        return np.concatenate(parts) if parts else np.zeros(0)

    @property
    def theta_names(self) -> list[str]:
        names = []
        for h in self._free():
            names += [h.name] if h.size == 1 else [f'{h.name}[{i}]' for i in range(h.size)]
        return names

    def display_name(self, name: str) -> str:
        """A parameter's name for people: the term it belongs to, then its own name
        ('k1__thrust_higher[1]' of ``FanJets + CentralRing`` -> 'FanJets.thrust_higher[1]')."""
        return f'{type(self).__name__}.{name}'

    @property
    def bounds(self) -> np.ndarray:
        """(n_theta, 2) lower and upper bound of each free parameter."""
        rows = [h.element_bounds() for h in self._free()]
        return np.vstack(rows) if rows else np.zeros((0, 2))

    def with_theta(self, theta) -> 'Term':
        """A copy whose free parameters are ``theta`` (the term itself is never mutated)."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (len(self.theta),):
            raise ConfigError(f'{type(self).__name__} has {len(self.theta)} free parameters, got {theta.shape}')
        params = self.get_params()
        i = 0
        for h in self._free():
            chunk = theta[i:i + h.size]
            params[h.name] = float(chunk[0]) if h.size == 1 and np.ndim(params[h.name]) == 0 else chunk.copy()
            i += h.size
        return self.clone(**params)

    def clone(self, **overrides) -> 'Term':
        params = self.get_params()
        params.update(overrides)
        return type(self)(self.fans, **params, fixed=self.fixed_names)

    @property
    def fixed_names(self) -> tuple[str, ...]:
        return tuple(h.name for h in self.hypers if h.fixed)

    def _init_hypers(self, fixed):
        """Copy the class declarations, marking the names in ``fixed`` as fixed."""
        fixed = set(fixed or ())
        unknown = fixed - {h.name for h in type(self).hypers}
        if unknown:
            raise ConfigError(f'{type(self).__name__} has no parameters {sorted(unknown)} to fix')
        self.hypers = tuple(Hyper(h.name, h.size, h.bounds, h.fixed or h.name in fixed)
                            for h in type(self).hypers)

    def _check_bounds(self):
        for h in self.hypers:
            v = np.atleast_1d(np.asarray(getattr(self, h.name), dtype=float))
            if v.shape != (h.size,):
                raise ConfigError(f'{type(self).__name__}.{h.name} needs {h.size} values, got {v.shape[0]}')
            lo, hi = h.element_bounds().T
            if not np.all(np.isfinite(v)) or np.any(v < lo) or np.any(v > hi):
                raise ConfigError(f'{type(self).__name__}.{h.name} = {v.tolist()} is outside its '
                                  f'bounds {np.column_stack([lo, hi]).tolist()}')

    # -- composition ---------------------------------------------------------------------------
    def __add__(self, other: 'Term') -> 'Term':
        return Sum(self, other)

    def __mul__(self, other: 'Term') -> 'Term':
        return Product(self, other)

    # -- persistence ---------------------------------------------------------------------------
    def to_dict(self) -> dict:
        out = {'kind': self.kind}
        for name, value in self.get_params().items():
            out[name] = np.asarray(value).tolist()
        if self.fixed_names:
            out['fixed'] = list(self.fixed_names)
        return out


class _Composite(Term):
    """Common code of Sum and Product: parameters are the children's, prefixed k1__ / k2__."""

    def __init__(self, k1: Term, k2: Term):
        if k1.fans != k2.fans:
            raise ConfigError('cannot combine terms built for different fan arrays')
        self.k1, self.k2 = k1, k2
        self.fans = k1.fans

    def get_params(self) -> dict:
        out = {f'k1__{k}': v for k, v in self.k1.get_params().items()}
        out.update({f'k2__{k}': v for k, v in self.k2.get_params().items()})
        return out

    @property
    def theta(self):
        return np.concatenate([self.k1.theta, self.k2.theta])

    @property
    def theta_names(self):
        return [f'k1__{n}' for n in self.k1.theta_names] + [f'k2__{n}' for n in self.k2.theta_names]

    @property
    def bounds(self):
        return np.vstack([self.k1.bounds, self.k2.bounds])

    def display_name(self, name: str) -> str:
        for prefix, child in (('k1__', self.k1), ('k2__', self.k2)):
            if name.startswith(prefix):
                return child.display_name(name[len(prefix):])
        return super().display_name(name)

    @property
    def fixed_names(self):
        return tuple(f'k1__{n}' for n in self.k1.fixed_names) + tuple(f'k2__{n}' for n in self.k2.fixed_names)

    def with_theta(self, theta):
        theta = np.asarray(theta, dtype=float)
        n1 = len(self.k1.theta)
        if theta.shape != (n1 + len(self.k2.theta),):
            raise ConfigError(f'{type(self).__name__} has {n1 + len(self.k2.theta)} free parameters, got {theta.shape}')
        return type(self)(self.k1.with_theta(theta[:n1]), self.k2.with_theta(theta[n1:]))

    def clone(self, **overrides):
        o1 = {k[4:]: v for k, v in overrides.items() if k.startswith('k1__')}
        o2 = {k[4:]: v for k, v in overrides.items() if k.startswith('k2__')}
        return type(self)(self.k1.clone(**o1), self.k2.clone(**o2))

    def to_dict(self):
        return {'kind': self.kind, 'terms': [self.k1.to_dict(), self.k2.to_dict()]}

    def leaves(self) -> list[Term]:
        out = []
        for k in (self.k1, self.k2):
            out += k.leaves() if isinstance(k, _Composite) else [k]
        return out


class Sum(_Composite):
    """Superposition: Phi = k1 + k2."""

    kind = 'sum'

    def _value_and_grad(self, U, Z, jacobian):
        v1, j1 = self.k1._value_and_grad(U, Z, jacobian)
        v2, j2 = self.k2._value_and_grad(U, Z, jacobian)
        return v1 + v2, (j1 + j2 if jacobian else None)

    def sparse_jacobian(self, U, Z, tol: float = 1e-6):
        return (self.k1.sparse_jacobian(U, Z, tol) + self.k2.sparse_jacobian(U, Z, tol)).tocsc()

    def __repr__(self):
        return f'{self.k1!r} + {self.k2!r}'


class Product(_Composite):
    """Modulation: Phi = k1 * k2 (e.g. jets times a wall attenuation)."""

    kind = 'product'

    def _value_and_grad(self, U, Z, jacobian):
        v1, j1 = self.k1._value_and_grad(U, Z, jacobian)
        v2, j2 = self.k2._value_and_grad(U, Z, jacobian)
        jac = j1 * v2[:, None] + v1[:, None] * j2 if jacobian else None
        return v1 * v2, jac

    def __repr__(self):
        def wrap(k):
            return f'({k!r})' if isinstance(k, Sum) else repr(k)
        return f'{wrap(self.k1)} * {wrap(self.k2)}'


#: Registry of term kinds that a model file may name. Every kind of this package registers
#: itself here when its module is imported (``wind_shaper.model`` imports them all); plugins
#: add theirs.
TERMS: dict[str, type] = {}


def register_term(cls: type) -> type:
    """Class decorator: make a Term subclass loadable from model files by its ``kind``."""
    if not (isinstance(cls, type) and issubclass(cls, Term) and cls.kind):
        raise ConfigError(f'{cls!r} is not a Term subclass with a kind')
    TERMS[cls.kind] = cls
    return cls


def term_from_dict(spec: Mapping, fans: FanArray) -> Term:
    """Build a term (tree) from its ``to_dict`` form."""
    if not isinstance(spec, Mapping) or 'kind' not in spec:
        raise ModelFileError(f'a model term must be a mapping with a "kind"; got {excerpt(spec)}')
    spec = dict(spec)
    kind = spec.pop('kind')
    if not isinstance(kind, str):
        raise ModelFileError(f'a model term\'s kind must be a name; got {excerpt(kind)}')
    if kind in ('sum', 'product'):
        terms = [term_from_dict(t, fans) for t in spec.get('terms', [])]
        if len(terms) < 2:
            raise ModelFileError(f'a {kind} needs at least two terms')
        out = terms[0]
        for t in terms[1:]:
            out = out + t if kind == 'sum' else out * t
        return out
    # Every kind of this package is registered already: importing this module ran the
    # package's __init__, which imports them all.
    cls = TERMS.get(kind)
    if cls is None:
        # A kind of the user's own: the plugins listed in WIND_SHAPER_PLUGINS may define it.
        try:
            load_plugins(env=True)
        except ConfigError as exc:
            raise ModelFileError(f'model term kind {excerpt(kind)} is not known yet and {exc}') from None
        cls = TERMS.get(kind)
    if cls is None:
        raise ModelFileError(f'unknown model term kind {excerpt(kind)} (known kinds: {sorted(TERMS)}); if it is '
                             f'a term of your own, {HOW_TO_LOAD}')
    try:
        return cls(fans, **spec)
    except (TypeError, ValueError, IndexError, KeyError, AttributeError, OverflowError,
            ArithmeticError) as exc:  # ConfigError is a ValueError too
        raise ModelFileError(f'cannot build term {kind!r} from {excerpt(spec, 200)}: '
                             f'{excerpt(str(exc), 200, quote=False)}; every parameter '
                             f'must be a number or a list of numbers') from None


def finite_difference_jacobian(term: Term, U, Z, step: float = 1e-6) -> np.ndarray:
    """Central-difference dPhi/dU, for tests and for terms without an analytic Jacobian."""
    U = np.asarray(U, dtype=float)
    J = np.zeros((len(np.asarray(Z).reshape(-1, 2)), term.n_fans))
    for j in range(term.n_fans):
        e = np.zeros_like(U)
        e[..., j] = step
        J[:, j] = (term(U + e, Z) - term(U - e, Z)) / (2 * step)
    return J

