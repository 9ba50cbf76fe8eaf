"""The coarse physical prior Phi_pr(U, z) as composable terms.

A term maps fan commands U [fraction 0..1, one per fan] and plate-centre points z [m, tunnel
frame] to the vertical force on the plate [N], and gives its Jacobian dPhi/dU [N per unit
PWM]. Terms add and multiply like scikit-learn kernels (``jets + ring``, ``jets * wall``), keep
their parameters only in ``__init__``, declare each parameter's bounds (or fix it) and print
their formula in ``repr``. ``theta`` is the vector of free parameters, which is what a fit moves.

Evaluation is batched: ``U`` is either one command vector (n_fans,) applied at every point,
or one row per point (M, n_fans) paired with ``Z`` (M, 2).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError, ModelFileError
from ..core.geometry import FanArray


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
    Z = np.asarray(Z, dtype=float).reshape(-1, 2)
    U = np.asarray(U, dtype=float)
    if U.ndim == 1:
        if U.shape[0] != n_fans:
            raise ConfigError(f'command vector has {U.shape[0]} entries for {n_fans} fans')
        U = np.broadcast_to(U, (len(Z), n_fans))
    elif U.shape != (len(Z), n_fans):
        raise ConfigError(f'commands {U.shape} do not pair with points {Z.shape} for {n_fans} fans')
    return U, Z


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


def _poly(coeffs, U):
    """Quadratic c0 + c1 U + c2 U^2 and its derivative; coeffs (..., 3) broadcast against U."""
    c0, c1, c2 = coeffs[..., 0], coeffs[..., 1], coeffs[..., 2]
    return c0 + c1 * U + c2 * U * U, c1 + 2.0 * c2 * U


def _sq_dist(Z, centres):
    """Squared distances (M, n) [m^2] from points Z (M, 2) to centres (n, 2)."""
    d = Z[:, None, :] - centres[None, :, :]
    return np.einsum('mnk,mnk->mn', d, d)


#: (point, fan) pairs evaluated at once by the dense fallback of ``Term.sparse_jacobian``.
_PAIRS_PER_BLOCK = 1 << 21


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


#: Registry of term kinds that a model file may name. The workbench adds effect terms here.
TERMS: dict[str, type] = {'fan_jets': FanJets, 'central_ring': CentralRing}


def register_term(cls: type) -> type:
    """Class decorator: make a Term subclass loadable from model files by its ``kind``."""
    if not (isinstance(cls, type) and issubclass(cls, Term) and cls.kind):
        raise ConfigError(f'{cls!r} is not a Term subclass with a kind')
    TERMS[cls.kind] = cls
    return cls


def paper_prior(fans: FanArray) -> Term:
    """The paper's prior structure with rough starting values (fit it before use)."""
    jets = FanJets(fans)
    if fans.group_mask('central').any():
        return jets + CentralRing(fans)
    return jets


def term_from_dict(spec: Mapping, fans: FanArray) -> Term:
    """Build a term (tree) from its ``to_dict`` form."""
    if not isinstance(spec, Mapping) or 'kind' not in spec:
        raise ModelFileError(f'a model term must be a mapping with a "kind"; got {spec!r}')
    spec = dict(spec)
    kind = spec.pop('kind')
    if kind in ('sum', 'product'):
        terms = [term_from_dict(t, fans) for t in spec.get('terms', [])]
        if len(terms) < 2:
            raise ModelFileError(f'a {kind} needs at least two terms')
        out = terms[0]
        for t in terms[1:]:
            out = out + t if kind == 'sum' else out * t
        return out
    cls = TERMS.get(kind)
    if cls is None:
        # The candidate-effect library registers its kinds on import; load it on first need so
        # a model file naming them reads anywhere (the workbench's `model add` writes such files).
        from . import effects  # noqa: F401
        cls = TERMS.get(kind)
    if cls is None:
        # A kind of the user's own: the plugins listed in WIND_SHAPER_PLUGINS may define it.
        from .plugins import HOW_TO_LOAD, load_plugins
        try:
            load_plugins(env=True)
        except ConfigError as exc:
            raise ModelFileError(f'model term kind {kind!r} is not known yet and {exc}') from None
        cls = TERMS.get(kind)
    if cls is None:
        raise ModelFileError(f'unknown model term kind {kind!r} (known kinds: {sorted(TERMS)}); if it is '
                             f'a term of your own, {HOW_TO_LOAD}')
    try:
        return cls(fans, **spec)
    except (TypeError, ValueError) as exc:  # ConfigError is a ValueError too
        raise ModelFileError(f'cannot build term {kind!r} from {spec}: {exc}; every parameter '
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

