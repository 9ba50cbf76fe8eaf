"""Is a target within what the fans can deliver? A quick check before a run spends sweeps on it.

The prior model says how much force the fans give at each key point. A target whose average or
peak is far above what every fan at its upper bound gives, or that asks for a downward force, can
only end with every fan saturated and a large error; it is refused with the numbers, so the user
can pick a level the tunnel can reach. The bound is the model's, so a margin (``slack``) keeps
targets near the limit, which the online loop may still reach on the real field.

Forces [N] along the tunnel axis at key points (x, y) [m, tunnel frame]; commands [fraction].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import TargetError

#: Command levels at which the model is evaluated for its upper bound: thrust grows with command
#: for the paper's terms, but a workbench effect (dead band, offset) need not be monotone.
LEVELS = 6


@dataclass(frozen=True)
class Reach:
    """What the model says the fans can do at the key points: the largest mean force [N] and the
    largest force at any key point [N], over commands from u_min to u_max (equal on all enabled
    fans), and the command level that gives them."""

    mean_max: float
    peak_max: float
    level: float


def model_reach(model, key_points, u_min: float, u_max: float, enabled) -> Reach:
    """The model's upper bounds on mean and peak force over equal commands in [u_min, u_max]."""
    enabled = np.asarray(enabled, dtype=bool)
    levels = np.linspace(u_min, u_max, LEVELS)
    Z = np.asarray(key_points, dtype=float)
    best_mean, best_peak, best_level = -np.inf, -np.inf, u_max
    for level in levels:
        U = np.where(enabled, level, 0.0)
        F = np.asarray(model(U, Z), dtype=float)
        if F.mean() > best_mean:
            best_mean, best_level = float(F.mean()), float(level)
        best_peak = max(best_peak, float(F.max()))
    return Reach(best_mean, best_peak, best_level)


def check_reachable(values, key_points, model, u_min: float, u_max: float, enabled, *,
                    what: str = 'the target', slack: float = 1.25, noise_N: float = 0.1) -> Reach:
    """Raise TargetError when ``values`` (N,) [N] at ``key_points`` are plainly out of reach:
    a mean above ``slack`` x the model's largest mean force, a peak above ``slack`` x its largest
    force anywhere, or a force below -``noise_N`` (the fans only blow one way). Returns the
    model's reach otherwise."""
    values = np.asarray(values, dtype=float)
    reach = model_reach(model, key_points, u_min, u_max, enabled)
    low = float(values.min())
    if low < -noise_N:
        raise TargetError(
            f'{what} asks for {low:.2f} N somewhere, a downward force; the fans only push air up '
            f'the tunnel: give a target >= 0 N everywhere')
    mean = float(values.mean())
    if mean > slack * reach.mean_max:
        raise TargetError(
            f'{what} asks for {mean:.2f} N on average over the key points, but with every fan at '
            f'up to u_max = {u_max:g} the model gives at most {reach.mean_max:.2f} N on average: '
            f'the fans cannot reach it. Lower the target (e.g. uniform:{0.8 * reach.mean_max:.1f}) '
            f'or raise shaping.u_max if the fans allow it')
    peak = float(values.max())
    if peak > slack * reach.peak_max:
        raise TargetError(
            f'{what} asks for {peak:.2f} N at its peak, but the model gives at most '
            f'{reach.peak_max:.2f} N at any key point with every fan at up to u_max = {u_max:g}: '
            f'lower the peak or raise shaping.u_max if the fans allow it')
    return reach


__all__ = ['Reach', 'model_reach', 'check_reachable']
