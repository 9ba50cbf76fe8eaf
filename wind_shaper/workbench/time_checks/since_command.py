"""Do the first seconds of a sweep read the previous commands?

When a sweep starts before the fans have reached its commands, its first seconds measure a
field between the previous sweep's commands and its own. The model says what that difference
looks like: g = model(previous commands, z) - model(this sweep's commands, z) at each sample's
place z. With a first-order lag of time constant tau the fans run, s seconds after the command
changed, at u(s) = u + (u_prev - u) exp(-s / tau), and the sweep reads

    h(s, z) = model(u(s), z) - model(u, z)     (the model's own thrust curves bend it)

more than the model says.

The test compares each sample of a sweep's first half with the sample of its second half nearest
to the same place (within ``PAIR_M``): the same commands, the same place, later. A model error of
the field, which depends on place and commands, cancels in the difference; so does a sweep's own
level (a zero that moved between sweeps), and the sweeps' paths, which may start at the same
place every time, cannot fake it. The differences are fitted as

    r(s1) - r(s2) = A (h(s1, z1) - h(s2, z2))     (s: time since the sweep started [s])

for time constants tau on a grid up to a quarter of the shortest sweep, keeping the tau of the
least squared error. Then A is fitted sweep by sweep (each sweep one vote: one sweep after a
big change of the commands must not carry the test alone), on the sweeps whose lag term reaches
a tenth of the noise, and their mean tested against zero with the Student-t across them at the
level ``Recording.z``. A fault: A > 0 beyond that, and the start of a sweep off by a material
force (A rms(g)). The skip it names is how long the fading part stays
above a twentieth of the noise (the noise measured on such sweeps is itself inflated by the
fault), at most half the shortest sweep.

The first sweep is left out (nothing says what ran before it), and so is every sweep at the
previous one's commands (g = 0).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .base import Recording, TimeCheck, TimeResult, register_time_check, t_limit

__all__ = ['SinceCommand', 'TAUS', 'PAIR_M']

#: Time constants tried [s].
TAUS = (0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
#: The farthest apart [m] two samples of a sweep may be to count as the same place.
PAIR_M = 0.02


def _pairs(s, prev):
    """(s1, s2, z1, z2, u_prev, u, dr) of the sweep ``s`` after the sweep ``prev``: each
    first-half sample with the second-half sample nearest its place, within ``PAIR_M``."""
    half = s.t < 0.5 * s.duration
    early, late = np.flatnonzero(half), np.flatnonzero(~half)
    if len(early) < 10 or len(late) < 10:
        return None
    dist, k = cKDTree(s.Z[late]).query(s.Z[early])
    ok = dist <= PAIR_M
    if ok.sum() < 10:
        return None
    i, j = early[ok], late[k[ok]]
    r = s.residual
    return s.t[i], s.t[j], s.Z[i], s.Z[j], prev.U, s.U, r[i] - r[j]


def _lagged(model, t, Z, u_prev, u, tau: float) -> np.ndarray:
    """h(t, Z) [N]: what fans lagging with ``tau`` [s] add to the model's forces, t [s] after
    the command changed from ``u_prev`` to ``u`` (0 where less than 0.1 % of the change is left)."""
    left = np.exp(-t / tau)
    out = np.zeros(len(t))
    on = left > 1e-3
    if on.any():
        U = u[None, :] + (u_prev - u)[None, :] * left[on, None]
        out[on] = model(U, Z[on]) - model(np.broadcast_to(u, U.shape), Z[on])
    return out


def _fit(parts, tau: float, model, least: float):
    """(the pooled squared error, each sweep's A) for one ``tau``; ``parts``: per sweep the pairs
    of ``_pairs``; a sweep whose lag term is under ``least`` [N] RMS says nothing and is left out
    of the A's."""
    sse, shares = 0.0, []
    X = [_lagged(model, s1, z1, up, u, tau) - _lagged(model, s2, z2, up, u, tau)
         for s1, s2, z1, z2, up, u, _ in parts]
    xx = sum(float(x @ x) for x in X)
    if xx <= 0:
        return np.inf, []
    A = sum(float(x @ p[6]) for x, p in zip(X, parts)) / xx
    for x, p in zip(X, parts):
        e = p[6] - A * x
        sse += float(e @ e)
        if np.sqrt(np.mean(x ** 2)) >= least:
            shares.append(float(x @ p[6]) / float(x @ x))
    return sse, shares


@register_time_check
class SinceCommand(TimeCheck):
    name = 'since_command'
    question = 'Do the first seconds of a sweep read the previous commands?'

    def measure(self, rec: Recording, earlier: dict) -> TimeResult:
        parts, gs, shortest = [], [], np.inf
        for prev, s in zip(rec.sweeps[:-1], rec.sweeps[1:]):
            if np.allclose(prev.U, s.U):
                continue
            g = rec.model(np.broadcast_to(prev.U, (len(s.t), len(prev.U))), s.Z) - s.pred
            pairs = _pairs(s, prev)
            if pairs is not None:
                parts.append(pairs)
                gs.append(g)
                shortest = min(shortest, s.duration)
        if len(parts) < 4:
            return self.skipped(f'{len(parts)} sweeps follow a change of the commands and revisit '
                                f'their places: too few')
        taus = [tau for tau in TAUS if tau <= shortest / 4] or [TAUS[0]]
        least = 0.1 * rec.noise_sd
        tau, _, shares = min(((tau, *_fit(parts, tau, rec.model, least)) for tau in taus),
                             key=lambda f: f[1])
        if len(shares) < 4:
            return self.skipped(f'{len(shares)} sweeps change the commands enough to show a lag: '
                                f'too few')
        shares = np.array(shares)
        A = float(shares.mean())
        z = A / max(float(shares.std(ddof=1)) / np.sqrt(len(shares)), 1e-12)
        limit = t_limit(rec.z, len(shares) - 1)
        rms_g = float(np.sqrt(np.mean(np.concatenate(gs) ** 2)))
        start = A * rms_g
        fault = z >= limit and start >= rec.size
        # how long the fading part stays above a twentieth of the noise, in half seconds
        fade = tau * np.log(max(start / (0.05 * rec.noise_sd), 1.0))
        skip = max(float(min(np.ceil(2 * fade) / 2, np.floor(shortest / 2))), 0.5)
        numbers = {'share_at_start': A, 't': z, 't_limit': limit, 'tau_s': tau,
                   'start_error_N': start, 'skip_s': skip, 'sweeps': len(shares),
                   'pairs': int(sum(len(p[6]) for p in parts)), 'material_N': rec.size}
        message = (f'The first {skip:g} s of each sweep read the previous commands: right after a '
                   f'sweep starts, the residual follows the difference the model predicts between '
                   f'the previous sweep\'s commands and this one\'s, against the same places later '
                   f'in the sweep ({100 * A:.0f} % of it at the start, fading with a time constant '
                   f'of about {tau:g} s; t = {z:.1f}, the test\'s limit {limit:.1f}), a force of '
                   f'{start:.2f} N RMS against noise {rec.noise_sd:.3f} N. The fans had not settled '
                   f'when the sweep began: raise the coordinator\'s settle_s (the wait after the '
                   f'fans report the commands) by {skip:g} s, or repair these sweeps with '
                   f'--skip-first {skip:g} (the first {skip:g} s of each sweep left out).')
        return self.result(fault, numbers, message, f'--skip-first {skip:g}')
