"""Terms for what the library does not explain: ``Discrepancy`` and ``FieldFormula``.

Both are linear in their weights and hold no physics: they describe the residual of a model
as spatial modes times command features,

    delta(U, z) = sum_f phi_f(U) sum_k W[k, f] rho_k(z),

so a lab can add them to a model and shape with it while the physics is still unknown.
``Discrepancy`` uses Gaussian bumps rho_k on a grid (the weight-space form of a Gaussian
process over position and command features, in the Kennedy-O'Hagan sense; fitted by
``wind_shaper.workbench.discrepancy``), ``FieldFormula`` a few named modes (a tilt, a radial
bowl, a bump over one fan) so the fitted sum reads as a formula.

Command features phi_f(U), U [fraction of full PWM], thrust taken to grow as U^2, over the
enabled fans (n of them):

* ``one``: 1 (a fixed pattern, whatever the fans do);
* ``thrust``: sum U_j^2 / n (the total thrust, 1 with every fan at full PWM);
* ``balance``: sum s_j U_j^2 / n, s_j = +1 for a CCW fan, -1 for a CW one (what swirl follows);
* ``fan:NAME``: U_NAME^2 (one fan's thrust).

Units: positions [m, tunnel frame], weights [N], forces [N].
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.geometry import FanArray
from .terms import Term, _batch, register_term

__all__ = ['Discrepancy', 'FieldFormula', 'CommandScale', 'command_features', 'feature_words',
           'MODE_NAMES']

_GLOBAL_FEATURES = ('one', 'thrust', 'balance')


def _check_features(fans: FanArray, features) -> tuple[str, ...]:
    features = tuple(str(f) for f in features)
    for f in features:
        if f in _GLOBAL_FEATURES:
            continue
        if f.startswith('fan:') and f[4:] in fans.names:
            continue
        raise ConfigError(f'unknown command feature {f!r}: use one of {list(_GLOBAL_FEATURES)} or '
                          f'fan:NAME with NAME one of the tunnel\'s fans {list(fans.names)}')
    return features


def command_features(fans: FanArray, features, U: np.ndarray, jacobian: bool = False):
    """phi (M, F) for commands U (M, n_fans), and when asked dphi/dU (M, F, n_fans)."""
    U = np.atleast_2d(np.asarray(U, float))
    on = fans.enabled.astype(float)
    n = max(float(on.sum()), 1.0)
    sign = fans.spin_sign * on
    U2 = U * U
    phi = np.empty((len(U), len(features)))
    d = np.zeros((len(U), len(features), fans.n_fans)) if jacobian else None
    for i, f in enumerate(features):
        if f == 'one':
            phi[:, i] = 1.0
        elif f == 'thrust':
            phi[:, i] = U2 @ on / n
            if jacobian:
                d[:, i, :] = 2 * U * on / n
        elif f == 'balance':
            phi[:, i] = U2 @ sign / n
            if jacobian:
                d[:, i, :] = 2 * U * sign / n
        else:
            j = fans.names.index(f[4:])
            phi[:, i] = U2[:, j]
            if jacobian:
                d[:, i, j] = 2 * U[:, j]
    return phi, d


def feature_words(feature: str) -> str:
    """How a part that goes with ``feature`` scales, in words."""
    if feature == 'one':
        return 'stays the same whatever the fans do'
    if feature == 'thrust':
        return 'grows with the total thrust of all fans'
    if feature == 'balance':
        return 'follows the CW/CCW balance (the CCW fans\' thrust minus the CW fans\')'
    return f'follows fan {feature[4:]}\'s command (its thrust)'


class _ModeSum(Term):
    """Common code: delta = sum_f phi_f(U) (rho(z) @ W[:, f]). Subclasses give rho(Z) (M, K).
    Nothing here is moved by the model's least squares (no free parameters): the weights come
    from the workbench's own linear fit."""

    hypers = ()
    _BLOCK = 20000  # points per block: rho is (M, K)

    def _init_weights(self, fans, features, weights, n_modes):
        self.fans = fans
        self.features = _check_features(fans, features)
        w = np.asarray(weights, float)
        if w.size != n_modes * len(self.features):
            raise ConfigError(f'{type(self).__name__} needs {n_modes} x {len(self.features)} weights '
                              f'(modes x features), got {w.size}')
        self.weights = w.reshape(n_modes, len(self.features))
        if not np.all(np.isfinite(self.weights)):
            raise ConfigError(f'{type(self).__name__} weights must be finite numbers')

    def modes(self, Z: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def parts(self, U, Z) -> np.ndarray:
        """(M, F): each command feature's part of the value at (U, Z)."""
        U, Z = _batch(U, Z, self.n_fans)
        phi, _ = command_features(self.fans, self.features, U)
        return (self.modes(Z) @ self.weights) * phi

    def _value_and_grad(self, U, Z, jacobian):
        value = np.zeros(len(Z))
        jac = np.zeros((len(Z), self.n_fans)) if jacobian else None
        for lo in range(0, len(Z), self._BLOCK):
            sl = slice(lo, lo + self._BLOCK)
            spatial = self.modes(Z[sl]) @ self.weights          # (m, F)
            phi, dphi = command_features(self.fans, self.features, U[sl], jacobian)
            value[sl] = np.sum(spatial * phi, axis=1)
            if jacobian:
                jac[sl] = np.einsum('mf,mfj->mj', spatial, dphi)
        return value, jac

    def get_params(self) -> dict:
        return {'features': list(self.features), 'weights': self.weights}

    def clone(self, **overrides):
        params = self.get_params()
        params.update(overrides)
        return type(self)(self.fans, **params)

    def to_dict(self) -> dict:
        out = {'kind': self.kind}
        for name, value in self.get_params().items():
            out[name] = value if isinstance(value, (list, str)) else np.asarray(value).tolist()
        return out


@register_term
class Discrepancy(_ModeSum):
    """A model of the residual with no physics in it (Kennedy-O'Hagan discrepancy):

        delta(U, z) = sum_f phi_f(U) sum_k W[k, f] exp(-|z - c_k|^2 / (2 width^2))

    centres c_k (K, 2) [m], width [m], features (F names, see the module docstring), weights W
    (K, F) [N]; ``note``: what it was fitted to, in words (kept in the model file)."""

    kind = 'discrepancy'

    def __init__(self, fans: FanArray, centres, width, features, weights, note: str = '', fixed=()):
        self.centres = np.asarray(centres, float).reshape(-1, 2)
        self.width = float(width)
        if not self.width > 0:
            raise ConfigError(f'Discrepancy.width must be > 0 m, got {width}')
        self.note = str(note)
        self._init_weights(fans, features, weights, len(self.centres))

    def modes(self, Z):
        d2 = np.sum((Z[:, None, :] - self.centres[None]) ** 2, axis=2)
        return np.exp(-0.5 * d2 / self.width ** 2)

    def get_params(self):
        return {'centres': self.centres, 'width': self.width, **super().get_params(), 'note': self.note}

    def __repr__(self):
        return (f'Discrepancy({len(self.centres)} bumps of {100 * self.width:.0f} cm x '
                f'[{", ".join(self.features)}])')


@register_term
class CommandScale(_ModeSum):
    """A factor that follows the commands and is the same everywhere,

        s(U) = sum_f w_f phi_f(U)   (dimensionless; weights (1, F)),

    for Kennedy and O'Hagan's scale of a model: ``model * CommandScale(...)`` is the share of
    the model's own field that the tunnel gives more (or less), as a shared supply or inlet
    that sags as the total flow grows would."""

    kind = 'command_scale'

    def __init__(self, fans: FanArray, features, weights, fixed=()):
        self._init_weights(fans, features, weights, 1)

    def modes(self, Z):
        return np.ones((len(Z), 1))

    def plus_one(self) -> 'CommandScale':
        """1 + s(U), as a factor of the model it scales."""
        features, weights = list(self.features), self.weights[0].copy()
        if 'one' not in features:
            features, weights = ['one'] + features, np.concatenate([[0.0], weights])
        weights[features.index('one')] += 1.0
        return CommandScale(self.fans, features, weights)

    def __repr__(self):
        return 'CommandScale(' + ' + '.join(f'{w:+.3g} {f}' for f, w in zip(self.features, self.weights[0])) + ')'


#: The named spatial modes of ``FieldFormula`` (R: the normalising radius [m]) and their words.
MODE_NAMES = {
    'uniform': 'uniform',
    'x': 'x / R (a tilt along x)',
    'y': 'y / R (a tilt along y)',
    'r2': '(x^2 + y^2) / R^2 (a bowl: grows towards the edge)',
    'quad_c': '(x^2 - y^2) / R^2',
    'quad_s': '2 x y / R^2',
}


@register_term
class FieldFormula(_ModeSum):
    """A sparse formula for the residual: delta(U, z) = sum over (mode, feature) pairs of
    W * mode(z) * phi(U). Modes: the names of ``MODE_NAMES`` (with ``radius`` R [m]) and
    ``bump:FAN`` = exp(-|z - hub|^2 / (2 bump_width^2)) over a fan's hub (bump_width [m])."""

    kind = 'field_formula'

    def __init__(self, fans: FanArray, modes, features, weights, radius: float = 0.34,
                 bump_width: float = 0.08, note: str = '', fixed=()):
        self.mode_names = tuple(str(m) for m in modes)
        for m in self.mode_names:
            if m not in MODE_NAMES and not (m.startswith('bump:') and m[5:] in fans.names):
                raise ConfigError(f'unknown spatial mode {m!r}: use one of {list(MODE_NAMES)} or '
                                  f'bump:FAN with FAN one of {list(fans.names)}')
        self.radius, self.bump_width, self.note = float(radius), float(bump_width), str(note)
        if not (self.radius > 0 and self.bump_width > 0):
            raise ConfigError('FieldFormula radius and bump_width must be > 0 m')
        self._init_weights(fans, features, weights, len(self.mode_names))

    def modes(self, Z):
        x, y = Z[:, 0] / self.radius, Z[:, 1] / self.radius
        cols = []
        for m in self.mode_names:
            if m == 'uniform':
                cols.append(np.ones(len(Z)))
            elif m == 'x':
                cols.append(x)
            elif m == 'y':
                cols.append(y)
            elif m == 'r2':
                cols.append(x * x + y * y)
            elif m == 'quad_c':
                cols.append(x * x - y * y)
            elif m == 'quad_s':
                cols.append(2 * x * y)
            else:
                hub = self.fans.positions[self.fans.names.index(m[5:])]
                cols.append(np.exp(-0.5 * np.sum((Z - hub) ** 2, axis=1) / self.bump_width ** 2))
        return np.column_stack(cols) if cols else np.zeros((len(Z), 0))

    def get_params(self):
        return {'modes': list(self.mode_names), **super().get_params(), 'radius': self.radius,
                'bump_width': self.bump_width, 'note': self.note}

    def formula(self, digits: int = 3) -> str:
        """The formula in words: '0.120 N x y/R x thrust + ...' (R, the bumps' width in the
        module docstring)."""
        parts = []
        for k, m in enumerate(self.mode_names):
            for f, feat in enumerate(self.features):
                w = self.weights[k, f]
                if w == 0:
                    continue
                mode = '' if m == 'uniform' else (f' x bump over {m[5:]}' if m.startswith('bump:')
                                                   else f' x {MODE_NAMES[m].split(" (")[0]}')
                feature = {'one': '', 'thrust': ' x T', 'balance': ' x B'}.get(feat, f' x U_{feat[4:]}^2')
                parts.append(f'{w:+.{digits}f} N{mode}{feature}')
        return ' '.join(parts) if parts else '0'

    def __repr__(self):
        return f'FieldFormula({self.formula()})'
