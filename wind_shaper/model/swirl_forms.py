"""Other forms of the swirl family: what the angle the field turns by may follow.

``Swirl`` turns the field by an angle proportional to the CW/CCW imbalance ratio
b = (T_ccw - T_cw) / T (``SwirlQuadratic`` adds b|b|). A straightener may pass swirl by another
law; ``SwirlFollows`` states three, chosen by ``follows`` (structural):

* ``'difference'``: theta = gain * (T_ccw - T_cw) / thrust_ref: the net angular momentum itself,
  not its share of the flow (the swirl grows with the flow at a fixed balance);
* ``'sign'``: theta = gain * tanh(b / 0.05): a fixed turn whichever way the balance tips (a
  vane set that flips as soon as one sense dominates), smoothed over 5 % of imbalance;
* ``'total'``: theta = gain * T / thrust_ref: the field turns with the total thrust, whatever
  the balance (vanes that leave a fixed sense of swirl at any flow).

gain [rad] bounds -1.5..1.5 (0 = no swirl); thrust_ref [N] (structural) sets the scale of the
thrust laws. The diagnosis tries these when the swirl candidate explains much of a residual but
does not hold across sweeps (``workbench.family_forms``). Positions [m], forces [N].
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.geometry import FanArray
from .fanwise import fan_thrust_batched
from .flow_effects import Swirl
from .terms import Hyper, register_term

__all__ = ['SwirlFollows', 'SWIRL_LAWS']

#: follows -> the law in words, for findings and reports.
SWIRL_LAWS = {
    'difference': 'in the CCW minus the CW thrust (T_ccw - T_cw) / thrust_ref',
    'sign': 'in the sign of the CW/CCW imbalance (tanh(b / 0.05))',
    'total': 'in the total thrust T / thrust_ref, whatever the balance',
}
_SIGN_WIDTH = 0.05  # [-] imbalance over which the 'sign' law turns over


@register_term
class SwirlFollows(Swirl):
    """Hypothesis: swirl turns the field by an angle following ``follows`` (see the module
    docstring) rather than the imbalance ratio."""

    kind = 'swirl_follows'
    hypers = (Hyper('gain', 1, (-1.5, 1.5)),)

    def __init__(self, fans: FanArray, term, gain: float = 0.0, follows: str = 'difference',
                 thrust_ref: float = 10.0, fixed=()):
        if follows not in SWIRL_LAWS:
            raise ConfigError(f'SwirlFollows.follows must be one of {sorted(SWIRL_LAWS)}; got {follows!r}')
        if not thrust_ref > 0:
            raise ConfigError(f'SwirlFollows.thrust_ref must be > 0 N; got {thrust_ref}')
        self.follows, self.thrust_ref = follows, float(thrust_ref)
        super().__init__(fans, term, gain=gain, fixed=fixed)

    def _structure(self):
        return {'follows': self.follows, 'thrust_ref': self.thrust_ref}

    def angle(self, U, jacobian=False):
        """theta (M,) [rad] and, with ``jacobian``, dtheta/dU (M, n_fans)."""
        T, dT = fan_thrust_batched(self.inner, U, jacobian)
        s = self.fans.spin_sign
        if self.follows == 'difference':
            x, dx = (T @ s) / self.thrust_ref, (s[None, :] / self.thrust_ref if jacobian else None)
        elif self.follows == 'total':
            x, dx = T.sum(axis=1) / self.thrust_ref, (np.full((1, len(s)), 1 / self.thrust_ref)
                                                       if jacobian else None)
        else:
            S, W = T.sum(axis=1), T @ s
            ok = S > 1e-9
            safe = np.where(ok, S, 1.0)
            b = np.where(ok, W / safe, 0.0)
            x = np.tanh(b / _SIGN_WIDTH)
            if jacobian:
                db = (s[None, :] * safe[:, None] - W[:, None]) / safe[:, None] ** 2
                dx = np.where(ok[:, None], ((1 - x * x) / _SIGN_WIDTH)[:, None] * db, 0.0)
        theta = self.gain * x
        if not jacobian:
            return theta, None
        return theta, self.gain * dx * dT

    def __repr__(self):
        return f'SwirlFollows(theta = {self.gain:.3g} rad x {self.follows}) o ({self.inner!r})'
