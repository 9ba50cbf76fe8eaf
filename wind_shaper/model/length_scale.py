"""The length over which the fans can shape the field: beyond it a field estimate's fit pays a prior.

When the commands change by dU, the force on the plate at z [m, tunnel frame] changes by
sum_j dU_j phi_j(z), phi_j = dF/dU_j the fan's footprint [N per unit PWM]. With the fans'
changes independent, that change is a random field of covariance sum_j phi_j(z) phi_j(z'):
the footprints' autocorrelation. A Gaussian footprint of sd sigma gives a squared exponential
of length sqrt(2) sigma, the distance at which the autocorrelation has fallen to exp(-1/2).

A field estimate that fits a longer length scale to a sweep says the field is smoother than any
change of the fans leaves it. On a dense fan wall the field's overall shape (the sum of many
jets) draws the likelihood to such a length: the estimate then rounds off the peak over one fan
and its std, too small there, does not say so. ``footprint_length_scale`` measures the
footprints' length on the prior model; ``FieldEstimator.max_length_scale`` bounds the fit by it
(softly: a sweep whose data clearly say longer still gets a longer length).
"""
from __future__ import annotations

import numpy as np

#: the autocorrelation's level at one squared-exponential length: exp(-1/2)
_AT_ONE_LENGTH = float(np.exp(-0.5))

#: up to this many fans the whole Jacobian on a footprint's grid is cheaper than the sparse one
_DENSE_UP_TO = 64


def _fall_off(autocorrelation: np.ndarray, step: float) -> float | None:
    """The shift [m] at which a normalised autocorrelation (by whole cells, from shift 0) first
    falls to exp(-1/2), interpolated between cells; None when it never does on the grid."""
    below = np.flatnonzero(autocorrelation < _AT_ONE_LENGTH)
    if len(below) == 0:
        return None
    s = int(below[0])
    a0, a1 = autocorrelation[s - 1], autocorrelation[s]
    return step * (s - 1 + (a0 - _AT_ONE_LENGTH) / (a0 - a1))


def _autocorrelation(F: np.ndarray, axis: int) -> np.ndarray:
    """sum F(i) F(i + s) / sum F^2 along ``axis`` for shifts s = 0 .. n-1 of a 2-D grid F."""
    F = np.moveaxis(F, axis, 0)
    n = F.shape[0]
    norm = float(np.sum(F * F))
    return np.array([float(np.sum(F[: n - s] * F[s:])) / norm for s in range(n)])


def _footprint_length(model, U, j: int, hub, reach: float, step: float) -> float | None:
    """Fan j's footprint length [m] on a square grid around its ``hub`` (see
    ``footprint_length_scale``); None when its footprint is zero or never falls off."""
    offsets = np.arange(-reach, reach + step / 2, step)
    gx, gy = np.meshgrid(offsets, offsets)
    grid = np.column_stack([gx.ravel() + hub[0], gy.ravel() + hub[1]])
    if len(U) > _DENSE_UP_TO:   # a large wall: only the fans that reach the grid
        F = model.sparse_jacobian(U, grid)[:, [j]].toarray()
    else:
        F = np.asarray(model.jacobian(U, grid), dtype=float)[:, j]
    F = F.reshape(gx.shape)
    if not np.any(F):
        return None
    along = [_fall_off(_autocorrelation(F, axis), step) for axis in (1, 0)]
    return None if any(a is None for a in along) else 0.5 * (along[0] + along[1])


def footprint_length_scale(model, fans=None, *, command: float = 0.5, reach: float = 0.6,
                           step: float = 0.01, most_fans: int = 9) -> float | None:
    """The squared-exponential length [m] that the fans' footprints in ``model`` imply (module
    docstring): per fan, the shift along x and along y at which its footprint's
    autocorrelation falls to exp(-1/2), averaged over the two; the median over up to
    ``most_fans`` enabled fans of ``fans`` (a ``FanArray``; None: the model's own) spread over
    the array.

    Each footprint is the model's Jacobian column at every fan at ``command`` [PWM fraction],
    on a square grid of ``step`` [m] reaching ``reach`` [m] each way from the fan's hub, widened
    for a footprint longer than a third of it (one cut off by the grid would look narrower).
    None when no enabled fan has a
    footprint that falls off on its grid (a model without spatial structure)."""
    if not (0 < step < reach):
        raise ValueError(f'footprint grid needs 0 < step < reach [m]; got step {step}, reach {reach}')
    fans = model.fans if fans is None else fans
    hubs = np.asarray(fans.positions, dtype=float)
    enabled = np.flatnonzero(np.asarray(fans.enabled, dtype=bool))
    if len(enabled) == 0:
        return None
    spread = np.linspace(0, len(enabled) - 1, min(most_fans, len(enabled))).round().astype(int)
    chosen = enabled[np.unique(spread)]
    U = np.full(len(hubs), float(command))
    lengths = []
    for j in chosen:
        r, h = reach, step
        length = _footprint_length(model, U, j, hubs[j], r, h)
        # a footprint wider than a third of the grid's reach is cut off by it: widen the grid
        # (same number of cells) until the footprint fits, up to 16 times
        for _ in range(4):
            if length is None or length <= r / 3:
                break
            r, h = 2 * r, 2 * h
            length = _footprint_length(model, U, j, hubs[j], r, h)
        if length is not None:
            lengths.append(length)
    return float(np.median(lengths)) if lengths else None


__all__ = ['footprint_length_scale']
