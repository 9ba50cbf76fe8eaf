"""Secant (Broyden-type) correction of a Jacobian from measured changes of the field.

Between two iterations the commands moved by s (n_fans,) [fraction] and the field estimate at
the key points moved by y (N,) [N]. If a prior predicted a change p for that move, the part it
missed, r = y - p, is evidence about the prior's Jacobian error D along s: D s ~ r. With several
such pairs (the columns of S (n, m) and R (N, m)) the least-change multi-secant correction is

    D = argmin_D  sum_i ||r_i - D s_i||^2 + ridge ||D||_F^2  =  R (S^T S + ridge I)^-1 S^T,

the matrix of smallest size that explains the pairs (Broyden's "good" update is the one-pair
case with ridge = 0). D is kept as the low-rank factors R, K = (S^T S + ridge I)^-1 and S, so a
1,296-fan wall with 10,000 key points never forms an (N, n) matrix. The ridge keeps noisy pairs
from steps that are small compared with the noise of the field estimate from writing that noise
into the Jacobian; pairs whose step is below ``min_step`` are not used at all.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError


class SecantCorrection:
    """Multi-secant least-change correction D [N per unit PWM] of a Jacobian.

    ridge [unit PWM^2]: Tikhonov weight on ||D||_F^2 relative to the pairs' squared residuals
    (set it to noise variance / prior variance of D's entries); min_step [fraction]: pairs
    whose step is smaller than this in every fan are dropped; memory: at most this many of the
    most recent pairs are used.

    ``fit(steps, misses)`` returns self; fitted state: ``S_`` (n, m), ``R_`` (N, m), ``K_``
    (m, m), ``n_pairs_``.
    """

    def __init__(self, ridge: float = 1e-3, min_step: float = 0.01, memory: int = 8):
        if not ridge >= 0:
            raise ConfigError(f'secant ridge must be >= 0, got {ridge}')
        if not min_step >= 0:
            raise ConfigError(f'secant min_step must be >= 0, got {min_step}')
        if not (isinstance(memory, (int, np.integer)) and memory >= 1):
            raise ConfigError(f'secant memory must be a whole number >= 1, got {memory!r}')
        self.ridge = float(ridge)
        self.min_step = float(min_step)
        self.memory = int(memory)

    def fit(self, steps, misses) -> 'SecantCorrection':
        """steps (m, n) [fraction]: command changes; misses (m, N) [N]: the field changes the
        prior did not predict, oldest first."""
        S = np.atleast_2d(np.asarray(steps, dtype=float))
        R = np.atleast_2d(np.asarray(misses, dtype=float))
        if len(S) != len(R):
            raise ConfigError(f'{len(S)} steps but {len(R)} field changes')
        if not (np.all(np.isfinite(S)) and np.all(np.isfinite(R))):
            raise ConfigError('secant pairs contain NaN or inf')
        keep = np.max(np.abs(S), axis=1) >= self.min_step if S.size else np.zeros(0, bool)
        S, R = S[keep][-self.memory:], R[keep][-self.memory:]
        self.S_, self.R_ = S.T.copy(), R.T.copy()
        m = S.shape[0]
        self.n_pairs_ = m
        if m:
            G = self.S_.T @ self.S_ + self.ridge * np.eye(m)
            # pinv: two identical steps with ridge 0 are allowed (they just carry no new direction)
            self.K_ = np.linalg.pinv(G, rcond=1e-12, hermitian=True)
        else:
            self.K_ = np.zeros((0, 0))
        return self

    def _check(self):
        if not hasattr(self, 'K_'):
            raise ConfigError('the secant correction is not fitted: call fit(steps, misses) first')

    def matvec(self, v) -> np.ndarray:
        """D v: (n,) or (n, k) command changes -> (N,) or (N, k) field changes [N]."""
        self._check()
        v = np.asarray(v, dtype=float)
        if self.n_pairs_ == 0:
            return np.zeros((self.R_.shape[0],) + v.shape[1:])
        return self.R_ @ (self.K_ @ (self.S_.T @ v))

    def rmatvec(self, w) -> np.ndarray:
        """D^T w: (N,) or (N, k) -> (n,) or (n, k)."""
        self._check()
        w = np.asarray(w, dtype=float)
        if self.n_pairs_ == 0:
            return np.zeros((self.S_.shape[0],) + w.shape[1:])
        return self.S_ @ (self.K_.T @ (self.R_.T @ w))

    def matrix(self) -> np.ndarray:
        """D as a dense (N, n) array (small problems and tests)."""
        self._check()
        return self.R_ @ self.K_ @ self.S_.T if self.n_pairs_ else np.zeros((self.R_.shape[0], self.S_.shape[0]))


def broyden_update(J: np.ndarray, s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Broyden's "good" rank-one update: the J + (y - J s) s^T / (s^T s) closest to J (Frobenius)
    that maps the step s (n,) to the observed change y (N,). Returns a new array; s = 0 returns J."""
    J = np.asarray(J, dtype=float)
    s = np.asarray(s, dtype=float)
    ss = float(s @ s)
    if ss == 0.0:
        return J.copy()
    return J + np.outer(np.asarray(y, dtype=float) - J @ s, s) / ss
