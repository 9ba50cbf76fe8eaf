"""A target force profile given per key point in a CSV file (``CsvTarget``), and the template
such a file starts from (``write_template_csv``).

Frame and units everywhere in this module: x, y [m] in the tunnel frame (origin on the
tunnel axis); force [N], the vertical force on a 20 cm x 20 cm plate.
"""

import csv
import io
import math
from pathlib import Path

import numpy as np

from ..core.errors import LimitError, TargetError
from ..core.limits import DEFAULT_LIMITS
from ..core.safe_yaml import read_text_file
from .profiles import Target, _as_points, _finite_float, _point_text

__all__ = [
    'CsvTarget',
    'write_template_csv',
    'CSV_HEADER',
]


CSV_HEADER = ('x', 'y', 'force')
_TEMPLATE_HINT = 'write one row per key point, e.g. with `wind-shaper targets template`'


def _nearest(queries, references, exclude_self=False):
    """Index of and distance [m] to the nearest reference for every query (chunked, O(N*M))."""
    indices = np.zeros(len(queries), dtype=np.intp)
    distances = np.full(len(queries), np.inf)
    if len(references) == 0:
        return indices, distances
    for start in range(0, len(queries), 512):
        chunk = queries[start:start + 512]
        gaps = np.hypot(chunk[:, None, 0] - references[None, :, 0],
                        chunk[:, None, 1] - references[None, :, 1])
        rows = np.arange(len(chunk))
        if exclude_self:
            gaps[rows, rows + start] = np.inf
        indices[start:start + len(chunk)] = np.argmin(gaps, axis=1)
        distances[start:start + len(chunk)] = gaps[rows, indices[start:start + len(chunk)]]
    return indices, distances


def _read_csv(path):
    """Rows of a target CSV as (points (M, 2) [m], forces (M,) [N], line numbers (M,))."""
    try:
        text = read_text_file(path, limits=DEFAULT_LIMITS).removeprefix('\ufeff')
        lines = list(csv.reader(io.StringIO(text, newline='')))
    except FileNotFoundError:
        raise TargetError(f'target CSV {str(path)!r} does not exist: {_TEMPLATE_HINT}') from None
    except (OSError, LimitError, csv.Error) as error:
        raise TargetError(f'target CSV {str(path)!r} cannot be read: {error}') from None
    numbered = [(number, line) for number, line in enumerate(lines, start=1)
                if any(cell.strip() for cell in line)]
    if not numbered:
        raise TargetError(f'target CSV {str(path)!r} is empty: expected the header x,y,force')
    header = tuple(cell.strip().lower() for cell in numbered[0][1])
    if header != CSV_HEADER:
        raise TargetError(
            f'target CSV {str(path)!r} has header {",".join(numbered[0][1])!r}, expected '
            f'{",".join(CSV_HEADER)!r} (x, y in metres, force in newtons)')
    table, numbers = [], []
    for number, line in numbered[1:]:
        if len(line) != len(CSV_HEADER):
            raise TargetError(
                f'target CSV {str(path)!r} line {number} has {len(line)} cells, expected 3 '
                f'(x,y,force)')
        row = []
        for column, cell in zip(CSV_HEADER, line):
            try:
                value = float(cell)
            except ValueError:
                raise TargetError(
                    f'target CSV {str(path)!r} line {number}, column {column!r}: {cell!r} is '
                    f'not a number') from None
            if not math.isfinite(value):
                raise TargetError(
                    f'target CSV {str(path)!r} line {number}, column {column!r} is '
                    f'{cell.strip()}: every value must be finite')
            row.append(value)
        table.append(row)
        numbers.append(number)
    table = np.array(table, dtype=np.float64).reshape(-1, 3)
    return table[:, :2], table[:, 2], np.array(numbers, dtype=int)


class CsvTarget(Target):
    """Force values [N] given per key point in a CSV with header ``x,y,force`` (x, y [m]).

    The file must hold exactly one row per key point (``key_points`` (K, 2) [m]); a row
    matches a point within ``tolerance`` [m]. The file is read and checked on construction.
    """

    name = 'csv'

    def __init__(self, path, key_points, tolerance=1e-3):
        self.path = Path(path)
        self.tolerance = _finite_float(tolerance, 'CSV tolerance [m]')
        if self.tolerance <= 0.0:
            raise TargetError(f'CSV tolerance must be > 0 m, got {self.tolerance!r}')
        self.key_points = _as_points(key_points)
        points, forces, lines = _read_csv(self.path)
        where = f'target CSV {str(self.path)!r}'
        others, gaps = _nearest(points, points, exclude_self=True)
        duplicate = np.flatnonzero(gaps <= self.tolerance)
        if duplicate.size:
            first = duplicate[0]
            raise TargetError(
                f'{where}: lines {lines[first]} and {lines[others[first]]} are the same point '
                f'{_point_text(points[first])} within {self.tolerance:g} m: keep one of them')
        if len(points) != len(self.key_points):
            raise TargetError(
                f'CSV has {len(points)} rows, the tunnel has {len(self.key_points)} key points: '
                f'{_TEMPLATE_HINT} ({where})')
        self._points, self._forces = points, forces
        self._lines = lines
        matched = self._indices(self.key_points, 'key points')
        rows, counts = np.unique(matched, return_counts=True)
        if np.any(counts > 1):
            shared = np.flatnonzero(matched == rows[np.argmax(counts > 1)])
            raise TargetError(
                f'{where}: key points {_point_text(self.key_points[shared[0]])} and '
                f'{_point_text(self.key_points[shared[1]])} both match line '
                f'{lines[matched[shared[0]]]}: use a tolerance below half the key-point spacing')

    def _indices(self, points, what):
        indices, gaps = _nearest(points, self._points)
        missing = np.flatnonzero(gaps > self.tolerance)
        if missing.size:
            first = missing[0]
            raise TargetError(
                f'target CSV {str(self.path)!r}: {missing.size} of {len(points)} {what} have no '
                f'row within {self.tolerance:g} m, e.g. {_point_text(points[first])} (nearest '
                f'row, line {self._lines[indices[first]]}, is {gaps[first]:.3g} m away): '
                f'{_TEMPLATE_HINT}')
        return indices

    def values(self, points):
        return self._forces[self._indices(_as_points(points), 'points')].copy()

    def describe(self):
        return (f'csv: {self.path} ({len(self._forces)} key points, '
                f'{self._forces.min():g} to {self._forces.max():g} N)')

    def __repr__(self):
        return (f'CsvTarget(path={str(self.path)!r}, key_points=<{len(self.key_points)} points>, '
                f'tolerance={self.tolerance!r})')


def write_template_csv(path, points, values):
    """Write a target CSV with header x,y,force: ``points`` (N, 2) [m], ``values`` [N].

    ``values`` is (N,) or a scalar (the same force at every point). Floats are written at full
    precision so the file reads back exactly. Returns the path.
    """
    array = _as_points(points)
    try:
        forces = np.broadcast_to(np.asarray(values, dtype=np.float64), (len(array),))
    except (TypeError, ValueError):
        raise TargetError(
            f'values must be a number or one force per point ({len(array)}), got shape '
            f'{np.shape(values)}') from None
    if not np.all(np.isfinite(forces)):
        raise TargetError('template values must be finite forces [N]')
    path = Path(path)
    with open(path, 'w', newline='', encoding='utf-8') as stream:
        writer = csv.writer(stream)
        writer.writerow(CSV_HEADER)
        for (x, y), force in zip(array, forces):
            writer.writerow([repr(float(x)), repr(float(y)), repr(float(force))])
    return path
