"""Do the first seconds of a sweep read the previous commands?

When a sweep starts before the fans have reached its commands, its first seconds measure a
field between the previous sweep's commands and its own. The model says what that difference
looks like: g = model(previous commands, z) - model(this sweep's commands, z) at each sample's
place z. The residual r is fitted per sample as

    r = b_k + c g + A exp(-s / tau) g     (s: time since the sweep started [s])

for time constants tau on a grid up to a quarter of the shortest sweep, keeping the tau of the
least squared error; b_k, a level of each sweep k, takes up what is constant over a sweep (a
zero that moved between sweeps, a model error of the sweep's commands), and c any model error
that merely resembles g, so only the part that fades with s counts. A's standard error is cluster-robust by sweep (the sweeps are the
independent units, gusts and path correlate samples within one). A fault: A > 0 at
``Recording.z`` standard errors, and the start of a sweep off by a material force (A rms(g)).
The skip it names is how long the fading part stays above a twentieth of the noise (the noise
measured on such sweeps is itself inflated by the fault), at most half the shortest sweep.

The first sweep is left out (nothing says what ran before it), and so is every sweep at the
previous one's commands (g = 0).
"""
from __future__ import annotations

import numpy as np

from .base import Recording, TimeCheck, TimeResult, register_time_check

__all__ = ['SinceCommand', 'TAUS']

#: Time constants tried [s].
TAUS = (0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0)


def _fit(parts, tau: float):
    """(A, its cluster-robust standard error, c, squared error) for one ``tau``; ``parts``: per
    sweep (s, g, r)."""
    X = [np.column_stack([g, np.exp(-s / tau) * g]) for s, g, r in parts]
    X = [x - x.mean(axis=0) for x in X]   # each sweep's own level (b_k) out
    R = [r - r.mean() for _, _, r in parts]
    XtX = sum(x.T @ x for x in X)
    Xtr = sum(x.T @ r for x, r in zip(X, R))
    try:
        bread = np.linalg.inv(XtX)
    except np.linalg.LinAlgError:
        return 0.0, np.inf, 0.0, np.inf
    beta = bread @ Xtr
    meat, sse = np.zeros((2, 2)), 0.0
    for x, r in zip(X, R):
        e = r - x @ beta
        u = x.T @ e
        meat += np.outer(u, u)
        sse += float(e @ e)
    k = len(parts)
    cov = bread @ meat @ bread * k / max(k - 1, 1)
    return float(beta[1]), float(np.sqrt(max(cov[1, 1], 0.0))), float(beta[0]), sse


@register_time_check
class SinceCommand(TimeCheck):
    name = 'since_command'
    question = 'Do the first seconds of a sweep read the previous commands?'

    def measure(self, rec: Recording, earlier: dict) -> TimeResult:
        parts = []
        for prev, s in zip(rec.sweeps[:-1], rec.sweeps[1:]):
            if np.allclose(prev.U, s.U):
                continue
            g = rec.model(np.broadcast_to(prev.U, (len(s.t), len(prev.U))), s.Z) - s.pred
            parts.append((s.t, g, s.residual))
        if len(parts) < 4:
            return self.skipped(f'{len(parts)} sweeps follow a change of the commands: too few')
        shortest = min(float(s[-1]) for s, _, _ in parts)
        taus = [tau for tau in TAUS if tau <= shortest / 4] or [TAUS[0]]
        fits = [(tau, *_fit(parts, tau)) for tau in taus]
        tau, A, se, c, _ = min(fits, key=lambda f: f[4])
        z = A / max(se, 1e-12)
        rms_g = float(np.sqrt(np.mean(np.concatenate([g for _, g, _ in parts]) ** 2)))
        start = A * rms_g
        fault = z >= rec.z and start >= rec.size
        # how long the fading part stays above a twentieth of the noise, in half seconds
        fade = tau * np.log(max(start / (0.05 * rec.noise_sd), 1.0))
        skip = float(min(np.ceil(2 * fade) / 2, np.floor(shortest / 2)))
        skip = max(skip, 0.5)
        numbers = {'share_at_start': A, 'z': z, 'tau_s': tau, 'start_error_N': start,
                   'skip_s': skip, 'sweeps': len(parts), 'material_N': rec.size}
        message = (f'The first {skip:g} s of each sweep read the previous commands: right after a '
                   f'sweep starts, the residual follows the difference the model predicts between '
                   f'the previous sweep\'s commands and this one\'s ({100 * A:.0f} % of it at the '
                   f'start, fading with a time constant of about {tau:g} s; {z:.0f} standard '
                   f'errors), a force of {start:.2f} N RMS against noise {rec.noise_sd:.3f} N. The '
                   f'fans had not settled when the sweep began: raise the coordinator\'s settle_s '
                   f'(the wait after the fans report the commands) by {skip:g} s, or repair these '
                   f'sweeps with --skip-first {skip:g} (the first {skip:g} s of each sweep left out).')
        return self.result(fault, numbers, message, f'--skip-first {skip:g}')
