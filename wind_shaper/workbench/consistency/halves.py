"""Does a value hold on both halves of an effect's footprint: on both sides of it
(``check_across_space``), and where the nearest fan runs high and low against the others
(``check_across_load``)? Forces [N], positions [m]."""
from __future__ import annotations

import numpy as np

from ...model import Term
from ..data import FitData
from ..fitting import fit_model
from .sweeps import _magnitude, _short, _term_elements

__all__ = ['check_across_space', 'check_across_load', 'across_space', 'across_load']


def _two_halves(model: Term, free: np.ndarray, train: FitData, diff: np.ndarray, halves,
                size: np.ndarray, magnitude: np.ndarray, names: list, tolerance: float,
                max_nfev: int):
    """Refit the ``free`` parameters of ``model`` on each of two row masks ``halves`` of
    ``train`` (the rest held) and compare them on the ``magnitude`` elements -> None when a
    half is too small, or when the effect (its change of the prediction ``diff``) barely
    reaches one half (under a quarter of the other's RMS change): not judged; else (short
    name, value on the first half, value on the second, z) of the element furthest apart, z
    in their standard errors and ``tolerance`` x the effect's size in quadrature (the halves
    differ when z > ``max_z``)."""
    fits, signal = [], []
    for rows in halves:
        signal.append(float(np.sqrt(np.mean(diff[rows] ** 2))) if rows.any() else 0.0)
        fits.append(fit_model(model, train.subset(rows), free=free, max_nfev=max_nfev)
                    if rows.sum() > 2 * free.sum() else None)
    if None in fits or min(signal) < 0.25 * max(signal):
        return None
    a, b = fits
    sigma = np.sqrt(a.theta_std ** 2 + b.theta_std ** 2 + (tolerance * size) ** 2)
    z = (np.abs(a.theta - b.theta) / sigma)[magnitude]
    i = int(np.flatnonzero(magnitude)[np.argmax(z)])
    return _short(names[i]), a.theta[i], b.theta[i], float(np.max(z))


def check_across_space(model: Term, label: str, null: dict, train: FitData, previous: Term,
                       **settings) -> str:
    """Does the term ``label`` of ``model`` hold on both sides of its footprint? '' if so,
    else why not, in words (``across_space``'s words)."""
    return across_space(model, label, null, train, previous, **settings)[1]


def across_space(model: Term, label: str, null: dict, train: FitData, previous: Term, *,
                 tolerance: float = 0.1, max_z: float = 3.0, min_signal: float = 0.02,
                 max_nfev: int = 20) -> tuple[dict, str]:
    """Does the term ``label`` of ``model`` hold on both sides of its footprint? (numbers, why
    not in words: '' if it does); numbers: per cut ('x', 'y') the two sides' distance in
    standard errors (None: not judged), and the footprint's centre [m].

    A real effect has one value wherever it is seen; a term that patches a pattern off to one
    side of its footprint (a blocked patch of the straightener beside a fan's hub, read as
    that jet's elongation or width) fits one side and not the other. The footprint is where
    the effect changes the prediction by ``min_signal`` [N] or more; it is cut through its
    centre (weighted by the change squared) along x and along y, and the term's magnitude
    parameters (see ``check_across_sweeps``) are refitted on every training cell of each side,
    the rest of the model held. A cut fails when the two sides' values differ by more than
    ``max_z`` times their standard errors and ``tolerance`` x the effect's size in quadrature;
    a side the effect barely reaches (under a quarter of the other's signal) is not judged."""
    sl, null_values, size = _term_elements(model, label, null)
    names = list(model.theta_names[sl])
    diff = model(train.U, train.Z) - previous(train.U, train.Z)
    foot = np.abs(diff) >= min_signal
    numbers = {'footprint_cells': int(foot.sum()), 'x': None, 'y': None}
    if foot.sum() < 20:
        return numbers, ''
    centre = np.average(train.Z[foot], axis=0, weights=diff[foot] ** 2)
    numbers['centre_m'] = [round(float(c), 4) for c in centre]
    free = np.zeros(len(model.theta), bool)
    free[sl] = True
    magnitude = _magnitude(null_values)
    for axis, word in ((0, 'x'), (1, 'y')):
        upper = train.Z[:, axis] >= centre[axis]
        halves = _two_halves(model, free, train, diff, (~upper, upper), size, magnitude, names,
                             tolerance, max_nfev)
        if halves is None:
            continue
        name, a, b, z = halves
        numbers[word] = round(z, 3)
        if z > max_z:
            return numbers, (f'it does not hold on both sides of its footprint: its {name} is '
                             f'{a:.3g} for {word} < {centre[axis]:+.2f} m and {b:.3g} '
                             f'beyond ({z:.1f} standard errors apart): it patches a pattern to one '
                             f'side')
    return numbers, ''


def check_across_load(model: Term, label: str, null: dict, train: FitData, previous: Term,
                      geometry, **settings) -> str:
    """Does the term ``label`` of ``model`` hold whether the fan nearest each place runs high or
    low against the others? '' if so, else why not, in words (``across_load``'s words)."""
    return across_load(model, label, null, train, previous, geometry, **settings)[1]


def across_load(model: Term, label: str, null: dict, train: FitData, previous: Term,
                geometry, *, tolerance: float = 0.1, max_z: float = 4.0,
                min_signal: float = 0.02, max_nfev: int = 20) -> tuple[dict, str]:
    """Does the term ``label`` of ``model`` hold whether the fan nearest each place runs high or
    low against the others? (numbers, why not in words: '' if it does); numbers: the median
    load the footprint is split at and the two halves' distance in standard errors (None: not
    judged).

    Every term of the library acts on the local flow or on the whole tunnel in a way its
    parameters fix: a boundary layer slows a share of the local flow, a worn fan gives a share
    of its thrust. Its value is then the same where the nearest fan runs harder than the rest
    of the tunnel and where it runs softer. Physics of another form is not: a return flow down
    the wall that follows the whole tunnel's thrust, read as a boundary layer, needs a thick
    layer beside a weak jet and a thin one beside a strong one; a fan whose ESC picks up
    another's signal needs a larger "gain" when it runs low. Each cell of the footprint (where
    the effect changes the prediction by ``min_signal`` [N] or more, in sweeps with a fan on)
    gets the load of its nearest enabled fan, U_j^2 over the sweep's mean U^2; the footprint is
    split at the median load, and the two halves are compared as the two sides of
    ``check_across_space``, but at ``max_z`` 4, not 3: it is put on every finding, and beside
    physics the library lacks the halves' cells carry a residual correlated in space that
    their standard errors do not know (a real tilted LM2 beside a blocked patch: 3.1 and 3.4
    standard errors; a return flow read as a wall layer: 7.6-8.2). It asks that the residual
    have no structure against each fan's command, put on the effect's own parameters."""
    sl, null_values, size = _term_elements(model, label, null)
    names = list(model.theta_names[sl])
    diff = model(train.U, train.Z) - previous(train.U, train.Z)
    enabled = np.asarray(geometry.fans.enabled, bool)
    u2 = np.asarray(train.U, float) ** 2
    mean = u2[:, enabled].mean(axis=1)
    hubs = np.asarray(geometry.fans.positions, float)
    d2 = ((train.Z[:, None, :] - hubs[None]) ** 2).sum(-1)
    d2[:, ~enabled] = np.inf
    nearest = np.argmin(d2, axis=1)
    load = u2[np.arange(len(nearest)), nearest] / np.maximum(mean, 1e-12)
    foot = (np.abs(diff) >= min_signal) & (mean > 1e-6)
    numbers = {'footprint_cells': int(foot.sum()), 'z': None}
    if foot.sum() < 20:
        return numbers, ''
    median = float(np.median(load[foot]))
    numbers['median_load'] = round(median, 4)
    high = load >= median
    free = np.zeros(len(model.theta), bool)
    free[sl] = True
    magnitude = _magnitude(null_values)
    halves = _two_halves(model, free, train, diff, (foot & ~high, foot & high), size, magnitude,
                         names, tolerance, max_nfev)
    if halves is None:
        return numbers, ''
    name, a, b, z = halves
    numbers['z'] = round(z, 3)
    if not z > max_z:
        return numbers, ''
    return numbers, (f'it does not hold at every load: its {name} is {a:.3g} where the nearest fan '
                     f'runs below {median:.2g} x the mean U^2 and {b:.3g} where it runs above '
                     f'({z:.1f} standard errors apart): the physics follows the fans\' commands '
                     f'in another way than this term')
