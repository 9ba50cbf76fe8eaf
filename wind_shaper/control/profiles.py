"""Target force profiles F_des(x, y): the ``Target`` interface and the profiles built from
parameters (``UniformTarget``, ``GaussianTarget``, ``ParabolicTarget``).

Frame and units everywhere in this module: x, y [m] in the tunnel frame (origin on the
tunnel axis); force [N], the vertical force on a 20 cm x 20 cm plate.

The other kinds live beside it: ``expression`` (``ExpressionTarget``, a user expression parsed
with a whitelist, never executed), ``csv_profile`` (``CsvTarget``, key-point values from a CSV);
``targets.make_target`` builds any of them from a config string or dict.
"""

import abc
import math

import numpy as np

from ..core.errors import TargetError

__all__ = [
    'Target',
    'UniformTarget',
    'GaussianTarget',
    'ParabolicTarget',
]


def _as_points(points):
    """Return ``points`` as a finite float64 (N, 2) array [m] or raise TargetError."""
    try:
        array = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise TargetError('points must be an (N, 2) array of numbers [m]') from None
    if array.ndim != 2 or array.shape[1] != 2:
        raise TargetError(f'points must have shape (N, 2) [m], got shape {array.shape}')
    if not np.all(np.isfinite(array)):
        raise TargetError('points must be finite; got NaN or inf coordinates')
    return array


def _finite_float(value, what):
    """Return ``value`` as a finite float; bools, non-numbers and NaN/inf raise TargetError."""
    if isinstance(value, (bool, np.bool_)):
        raise TargetError(f'{what} must be a number, got {value!r}')
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise TargetError(f'{what} must be a number, got {value!r}') from None
    if not math.isfinite(number):
        raise TargetError(f'{what} must be finite, got {value!r}')
    return number


def _is_pair(value):
    try:
        return np.shape(value) == (2,)
    except (TypeError, ValueError):
        return False


def _point_text(point):
    return f'(x={point[0]:.4g}, y={point[1]:.4g}) m'


class Target(abc.ABC):
    """A desired force profile F_des(x, y) [N] over the tunnel cross-section.

    ``name`` is the kind used by ``make_target`` ('uniform', 'gaussian', ...).
    """

    name = 'target'

    @abc.abstractmethod
    def values(self, points):
        """Desired force [N] at ``points`` (N, 2) [m, tunnel frame]; float64 (N,), all finite."""

    @abc.abstractmethod
    def describe(self):
        """One line for logs and reports, e.g. 'parabolic: 2.25 + 30*(x^2 + y^2) N'."""


class UniformTarget(Target):
    """The same force ``force`` [N] everywhere."""

    name = 'uniform'

    def __init__(self, force=2.5):
        self.force = _finite_float(force, 'uniform force [N]')

    def values(self, points):
        return np.full(len(_as_points(points)), self.force)

    def describe(self):
        return f'uniform: {self.force:g} N'

    def __repr__(self):
        return f'UniformTarget(force={self.force!r})'


class GaussianTarget(Target):
    """A bump: base + peak * exp(-|z - center|^2 / (2 width^2)) [N], z = (x, y) [m].

    peak, base [N]; center (x0, y0) [m, tunnel frame]; width [m] > 0 (standard deviation).
    """

    name = 'gaussian'

    def __init__(self, peak, center, width, base=0.0):
        self.peak = _finite_float(peak, 'gaussian peak [N]')
        center = np.asarray(center, dtype=np.float64) if _is_pair(center) else None
        if center is None or not np.all(np.isfinite(center)):
            raise TargetError('gaussian center must be a finite pair (x0, y0) [m]')
        self.center = (float(center[0]), float(center[1]))
        self.width = _finite_float(width, 'gaussian width [m]')
        if self.width <= 0.0:
            raise TargetError(f'gaussian width must be > 0 m, got {self.width!r}')
        self.base = _finite_float(base, 'gaussian base [N]')

    def values(self, points):
        offsets = _as_points(points) - np.asarray(self.center)
        squared = np.sum(offsets * offsets, axis=1)
        return self.base + self.peak * np.exp(-squared / (2.0 * self.width ** 2))

    def describe(self):
        x0, y0 = self.center
        return (f'gaussian: {self.base:g} + {self.peak:g}*exp(-((x - {x0:g})^2 + (y - {y0:g})^2)'
                f' / (2*{self.width:g}^2)) N')

    def __repr__(self):
        return (f'GaussianTarget(peak={self.peak!r}, center={self.center!r}, '
                f'width={self.width!r}, base={self.base!r})')


class ParabolicTarget(Target):
    """The soaring-robot profile: offset + curvature * (x^2 + y^2) [N].

    offset [N] on the axis; curvature [N/m^2].
    """

    name = 'parabolic'

    def __init__(self, offset=2.25, curvature=30.0):
        self.offset = _finite_float(offset, 'parabolic offset [N]')
        self.curvature = _finite_float(curvature, 'parabolic curvature [N/m^2]')

    def values(self, points):
        array = _as_points(points)
        return self.offset + self.curvature * np.sum(array * array, axis=1)

    def describe(self):
        return f'parabolic: {self.offset:g} + {self.curvature:g}*(x^2 + y^2) N'

    def __repr__(self):
        return f'ParabolicTarget(offset={self.offset!r}, curvature={self.curvature!r})'
