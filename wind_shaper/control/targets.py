"""Target force profiles F_des(x, y) for the plate above the fan array.

Frame and units everywhere in this module: x, y [m] in the tunnel frame (origin on the
tunnel axis); force [N], the vertical force on a 20 cm x 20 cm plate.

A target is built from parameters (``UniformTarget``, ``GaussianTarget``, ``ParabolicTarget``),
from a user expression (``ExpressionTarget``, parsed with a whitelist, never executed), or from
a CSV of key-point values (``CsvTarget``). ``make_target`` builds any of them from a config
string or dict.
"""

import abc
import ast
import csv
import math
from pathlib import Path

import numpy as np

from wind_shaper.core.errors import TargetError

__all__ = [
    'Target',
    'UniformTarget',
    'GaussianTarget',
    'ParabolicTarget',
    'ExpressionTarget',
    'CsvTarget',
    'make_target',
    'write_template_csv',
    'TARGET_KINDS',
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


def _short(text, limit=60):
    return text if len(text) <= limit else text[:limit - 3] + '...'


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


# --- expressions -------------------------------------------------------------------------------

MAX_EXPRESSION_LENGTH = 500
MAX_EXPRESSION_DEPTH = 50

_VARIABLES = ('x', 'y', 'r', 'theta')
_CONSTANTS = {'pi': math.pi, 'e': math.e}


def _clip(value, low, high):
    return np.minimum(np.maximum(value, low), high)


# name -> (number of arguments, elementwise numpy function)
_FUNCTIONS = {
    'sqrt': (1, np.sqrt),
    'exp': (1, np.exp),
    'log': (1, np.log),
    'sin': (1, np.sin),
    'cos': (1, np.cos),
    'tan': (1, np.tan),
    'atan2': (2, np.arctan2),
    'abs': (1, np.abs),
    'min': (2, np.minimum),
    'max': (2, np.maximum),
    'clip': (3, _clip),
    'where': (3, np.where),
}
_BINARY = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
           ast.Div: np.divide, ast.Pow: np.power}
_UNARY = {ast.UAdd: np.positive, ast.USub: np.negative}
_COMPARISONS = {ast.Lt: np.less, ast.LtE: np.less_equal,
                ast.Gt: np.greater, ast.GtE: np.greater_equal}
_OPERATOR_SYMBOLS = {
    ast.FloorDiv: '//', ast.Mod: '%', ast.MatMult: '@', ast.LShift: '<<', ast.RShift: '>>',
    ast.BitOr: '|', ast.BitXor: '^', ast.BitAnd: '&', ast.Invert: '~', ast.Not: 'not',
    ast.Eq: '==', ast.NotEq: '!=', ast.Is: 'is', ast.IsNot: 'is not', ast.In: 'in',
    ast.NotIn: 'not in', ast.And: 'and', ast.Or: 'or',
}
_CONSTRUCTS = {
    ast.Attribute: 'attribute access', ast.Subscript: 'subscript', ast.Slice: 'slice',
    ast.Lambda: 'lambda', ast.ListComp: 'list comprehension', ast.SetComp: 'set comprehension',
    ast.DictComp: 'dict comprehension', ast.GeneratorExp: 'generator expression',
    ast.JoinedStr: 'f-string', ast.FormattedValue: 'f-string',
    ast.NamedExpr: 'assignment expression (walrus :=)', ast.Starred: 'starred argument',
    ast.IfExp: "conditional expression 'a if c else b' (use where(c, a, b))",
    ast.BoolOp: "'and'/'or' (use where(...))", ast.List: 'list', ast.Tuple: 'tuple',
    ast.Dict: 'dict', ast.Set: 'set', ast.Await: 'await', ast.Yield: 'yield',
    ast.YieldFrom: 'yield from',
}
ALLOWED_EXPRESSIONS = (
    'allowed: numbers; names x, y [m], r = sqrt(x^2 + y^2) [m], theta = atan2(y, x) [rad], '
    'pi, e; unary + -; binary + - * / **; functions sqrt, exp, log, sin, cos, tan, atan2(y, x), '
    'abs, min(a, b), max(a, b), clip(v, lo, hi), where(cond, a, b) with a comparison '
    '< <= > >= as cond'
)


class _Compiler:
    """Turns a whitelisted AST into a closure env -> value, folding constant subtrees.

    Every compiled node is either a constant (np.float64 / np.bool_) or a callable taking the
    dict of variable arrays. Constants are folded in float64 under np.errstate, so an
    exponent tower such as 9**9**9 becomes inf (and is rejected) instead of a huge Python int.
    """

    def __init__(self, text):
        self.text = text

    def fail(self, node, what, why='is not allowed', allowed=True):
        """Raise TargetError: "<what> '<source of node>' at column <c> <why>; allowed: ..."."""
        segment = _short(ast.get_source_segment(self.text, node) or '', 40)
        message = (f'expression {_short(self.text)!r}: {what} {segment!r} at column '
                   f'{node.col_offset + 1} {why}')
        raise TargetError(message + (f'; {ALLOWED_EXPRESSIONS}' if allowed else ''))

    def build(self, node, depth=1):
        if depth > MAX_EXPRESSION_DEPTH:
            raise TargetError(
                f'expression {_short(self.text)!r} is nested more than {MAX_EXPRESSION_DEPTH} '
                f'levels deep: simplify it')
        if isinstance(node, ast.Constant):
            return self._constant(node)
        if isinstance(node, ast.Name):
            return self._name(node)
        if isinstance(node, ast.UnaryOp):
            if type(node.op) not in _UNARY:
                self.fail(node, f'operator {_OPERATOR_SYMBOLS.get(type(node.op), "?")!r} in')
            return self._combine(node, _UNARY[type(node.op)], [node.operand], depth)
        if isinstance(node, ast.BinOp):
            if type(node.op) not in _BINARY:
                self.fail(node, f'operator {_OPERATOR_SYMBOLS.get(type(node.op), "?")!r} in')
            return self._combine(node, _BINARY[type(node.op)], [node.left, node.right], depth)
        if isinstance(node, ast.Call):
            return self._call(node, depth)
        if isinstance(node, ast.Compare):
            self.fail(node, 'comparison', 'outside where(cond, a, b) is not allowed')
        self.fail(node, _CONSTRUCTS.get(type(node), f'construct {type(node).__name__}'))

    def _constant(self, node):
        value = node.value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            kind = {str: 'string literal', bytes: 'bytes literal', complex: 'complex number',
                    bool: 'boolean'}.get(type(value), f'literal of type {type(value).__name__}')
            self.fail(node, kind)
        try:
            number = np.float64(value)
        except OverflowError:
            self.fail(node, 'number', 'is too large for float64', allowed=False)
        if not np.isfinite(number):
            self.fail(node, 'number', 'is not finite', allowed=False)
        return number

    def _name(self, node):
        if node.id in _CONSTANTS:
            return np.float64(_CONSTANTS[node.id])
        if node.id in _VARIABLES:
            name = node.id
            return lambda env: env[name]
        if node.id in _FUNCTIONS:
            self.fail(node, 'function name', 'without a call is not allowed (write e.g. sin(x))')
        self.fail(node, 'name')

    def _call(self, node, depth):
        if not isinstance(node.func, ast.Name):
            self.build(node.func, depth + 1)  # reports what the callee is (attribute, ...)
            self.fail(node.func, 'call of')
        name = node.func.id
        if name in _VARIABLES or name in _CONSTANTS:
            self.fail(node.func, 'name', 'is not a function')
        if name not in _FUNCTIONS:
            self.fail(node.func, 'function')
        for argument in node.args:
            if isinstance(argument, ast.Starred):
                self.fail(argument, 'starred argument')
        if node.keywords:
            self.fail(node, f'keyword argument {node.keywords[0].arg!r} in')
        arity, function = _FUNCTIONS[name]
        if len(node.args) != arity:
            self.fail(node, 'call', f'passes {len(node.args)} argument(s); {name}() takes {arity}')
        if name != 'where':
            return self._combine(node, function, node.args, depth)
        condition = node.args[0]
        if not isinstance(condition, ast.Compare):
            self.fail(condition, 'condition', 'of where() must be a comparison < <= > >=')
        compiled_condition = self._comparison(condition, depth + 1)
        branches = [self.build(arg, depth + 1) for arg in node.args[1:]]
        return self._fold_or_wrap(node, np.where, [compiled_condition] + branches)

    def _comparison(self, node, depth):
        for op in node.ops:
            if type(op) not in _COMPARISONS:
                self.fail(node, f'comparison {_OPERATOR_SYMBOLS.get(type(op), "?")!r} in')
        tests = [_COMPARISONS[type(op)] for op in node.ops]

        def compare(*operands):  # chained: a < b < c means (a < b) & (b < c)
            result = tests[0](operands[0], operands[1])
            for test, left, right in zip(tests[1:], operands[1:], operands[2:]):
                result = np.logical_and(result, test(left, right))
            return result

        return self._combine(node, compare, [node.left] + node.comparators, depth)

    def _combine(self, node, function, children, depth):
        compiled = [self.build(child, depth + 1) for child in children]
        return self._fold_or_wrap(node, function, compiled)

    def _fold_or_wrap(self, node, function, compiled):
        if not any(callable(part) for part in compiled):
            with np.errstate(all='ignore'):
                value = function(*compiled)
            if np.issubdtype(np.asarray(value).dtype, np.floating) and not np.isfinite(value):
                self.fail(node, 'constant part', f'evaluates to {float(value)} (overflow or '
                          'invalid operation): bound the exponent or fix the constant',
                          allowed=False)
            return value
        parts = [part if callable(part) else _constant_function(part) for part in compiled]
        return lambda env: function(*[part(env) for part in parts])


def _constant_function(value):
    return lambda env: value


class ExpressionTarget(Target):
    """A force profile [N] written as an expression in x, y [m] (also r [m], theta [rad]).

    Example: ``ExpressionTarget('2.5 + 0.5*cos(3*theta) * r')``. The text is parsed with
    ``ast.parse`` and walked against a whitelist (see ``ALLOWED_EXPRESSIONS``); it is never
    passed to eval/exec/compile. Anything else raises TargetError naming the construct.
    """

    name = 'expr'

    def __init__(self, text):
        if not isinstance(text, str):
            raise TargetError(f'an expression must be a string, got {type(text).__name__}')
        if len(text) > MAX_EXPRESSION_LENGTH:
            raise TargetError(
                f'expression is too long ({len(text)} characters, at most '
                f'{MAX_EXPRESSION_LENGTH}): use a CSV target for complicated profiles')
        text = text.strip()  # the parser rejects leading blanks as an indent
        self.text = text
        if not text:
            raise TargetError(f'the expression is empty; {ALLOWED_EXPRESSIONS}')
        if '\0' in text:  # SyntaxError or ValueError depending on the Python version
            raise TargetError(
                f'expression {_short(text)!r} has a null byte at column {text.index(chr(0)) + 1}')
        try:
            tree = ast.parse(text, mode='eval')
        except SyntaxError as error:
            position = f'column {error.offset or len(text) + 1}'  # 0/None: at the end
            if error.lineno and error.lineno > 1:
                position = f'line {error.lineno}, {position}'
            raise TargetError(
                f'expression {_short(text)!r} has a syntax error at {position}: {error.msg}; '
                f'{ALLOWED_EXPRESSIONS}') from None
        except (RecursionError, MemoryError):
            raise TargetError(
                f'expression {_short(text)!r} is too deeply nested to parse: simplify it'
            ) from None
        except ValueError as error:
            raise TargetError(f'expression {_short(text)!r} cannot be parsed: {error}') from None
        self._function = _Compiler(text).build(tree.body)

    def values(self, points):
        array = _as_points(points)
        x, y = array[:, 0], array[:, 1]
        env = {'x': x, 'y': y, 'r': np.hypot(x, y), 'theta': np.arctan2(y, x)}
        with np.errstate(all='ignore'):
            raw = self._function(env) if callable(self._function) else self._function
        result = np.array(np.broadcast_to(np.asarray(raw, dtype=np.float64), (len(array),)))
        bad = ~np.isfinite(result)
        if np.any(bad):
            first = int(np.flatnonzero(bad)[0])
            raise TargetError(
                f'expression {_short(self.text)!r} is not finite at {int(bad.sum())} of '
                f'{len(array)} points, e.g. at {_point_text(array[first])} it gives '
                f'{result[first]} (division by zero, log or sqrt of a negative number?)')
        return result

    def describe(self):
        return f'expression: {" ".join(self.text.split())} N'

    def __repr__(self):
        return f'ExpressionTarget({self.text!r})'


# --- CSV -----------------------------------------------------------------------------------------

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
        with open(path, newline='', encoding='utf-8-sig') as stream:
            lines = list(csv.reader(stream))
    except FileNotFoundError:
        raise TargetError(f'target CSV {str(path)!r} does not exist: {_TEMPLATE_HINT}') from None
    except (OSError, UnicodeDecodeError, csv.Error) as error:
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


# --- factory ------------------------------------------------------------------------------------

# kind -> parameters accepted in a spec string 'kind:key=value,...' or a dict {'kind': ...}
TARGET_KINDS = {
    'uniform': ('force',),
    'gaussian': ('peak', 'width', 'base', 'x', 'y', 'fan'),
    'parabolic': ('offset', 'curvature'),
    'expr': ('text',),
    'csv': ('path', 'tolerance'),
}
_GAUSSIAN_DEFAULTS = {'peak': 2.0, 'base': 1.5, 'width': 0.12}


def _kinds_text():
    return ', '.join(f'{kind}({", ".join(keys)})' for kind, keys in TARGET_KINDS.items())


def _parse_parameters(kind, text):
    """'a=1,b=2' -> {'a': '1', 'b': '2'}; 'uniform:3' is short for 'uniform:force=3'."""
    if kind == 'uniform' and '=' not in text:
        return {'force': text.strip()}
    parameters = {}
    for item in text.split(','):
        key, equals, value = item.partition('=')
        if not equals:
            raise TargetError(
                f'target {kind!r}: write parameters as key=value separated by commas, got '
                f'{text!r}; valid keys: {", ".join(TARGET_KINDS[kind])}')
        parameters[key.strip()] = value.strip()
    return parameters


def _fan_center(fan, fan_positions, fan_names):
    if fan_positions is None or fan_names is None:
        raise TargetError(
            f'gaussian@{fan} needs the fan table: pass fan_names and fan_positions to make_target')
    names = [str(name) for name in fan_names]
    positions = np.asarray(fan_positions, dtype=np.float64)
    if positions.shape != (len(names), 2):
        raise TargetError(
            f'fan_positions must have shape ({len(names)}, 2) [m] to match fan_names, got '
            f'{positions.shape}')
    if fan not in names:
        shown = ', '.join(names[:12]) + (f', ... ({len(names)} fans)' if len(names) > 12 else '')
        raise TargetError(f'no fan named {fan!r}; fans are: {shown}')
    return positions[names.index(fan)]


def make_target(spec, *, fan_positions=None, fan_names=None, key_points=None):
    """Build a Target from a config string or dict.

    Strings: 'uniform', 'uniform:3.0', 'gaussian', 'gaussian@LM1', 'gaussian@LM1:peak=3',
    'gaussian:peak=2,width=0.1,x=0.1,y=0', 'parabolic', 'parabolic:offset=2,curvature=25',
    'expr:<expression in x, y>', 'csv:<path>'. Dicts: {'kind': 'gaussian', 'peak': 2.0, ...}
    with the keys listed in TARGET_KINDS. Units: forces [N], x, y, width [m], tolerance [m],
    curvature [N/m^2].

    fan_names (M,) and fan_positions (M, 2) [m] resolve 'gaussian@<fan>' / {'fan': ...};
    key_points (K, 2) [m] are required by csv targets. A Target passes through unchanged.
    """
    if isinstance(spec, Target):
        return spec
    if isinstance(spec, str):
        head, _, rest = spec.strip().partition(':')
        kind, at, fan = head.strip().partition('@')
        kind = kind.strip().lower()
        if kind not in TARGET_KINDS:
            raise TargetError(f'unknown target kind {kind!r} in {spec!r}; valid: {_kinds_text()}')
        if kind == 'expr':
            parameters = {'text': rest}
        elif kind == 'csv':
            parameters = {'path': rest.strip()}
        else:
            parameters = _parse_parameters(kind, rest) if rest.strip() else {}
        if at:
            if kind != 'gaussian':
                raise TargetError(f'only gaussian targets take @<fan>, got {spec!r}')
            parameters['fan'] = fan.strip()
    elif isinstance(spec, dict):
        parameters = dict(spec)
        kind = str(parameters.pop('kind', '')).strip().lower()
        if kind not in TARGET_KINDS:
            raise TargetError(
                f'target dict needs "kind" with a valid kind, got {spec.get("kind")!r}; valid: '
                f'{_kinds_text()}')
    else:
        raise TargetError(
            f'a target spec must be a string or a dict, got {type(spec).__name__}; valid kinds: '
            f'{_kinds_text()}')

    unknown = sorted(set(parameters) - set(TARGET_KINDS[kind]))
    if unknown:
        raise TargetError(
            f'unknown parameter(s) {", ".join(map(repr, unknown))} for a {kind} target; valid: '
            f'{", ".join(TARGET_KINDS[kind])}')

    if kind == 'uniform':
        return UniformTarget(**parameters)
    if kind == 'parabolic':
        return ParabolicTarget(**parameters)
    if kind == 'expr':
        if 'text' not in parameters:
            raise TargetError('an expr target needs "text", e.g. {"kind": "expr", "text": "2.5"}')
        return ExpressionTarget(parameters['text'])
    if kind == 'csv':
        if not parameters.get('path'):
            raise TargetError('a csv target needs a path, e.g. "csv:targets/bump.csv"')
        if key_points is None:
            raise TargetError(
                'a csv target needs the tunnel key points: pass key_points=(K, 2) [m]')
        return CsvTarget(parameters['path'], key_points, parameters.get('tolerance', 1e-3))
    fan = parameters.pop('fan', None)
    if fan is not None:
        if 'x' in parameters or 'y' in parameters:
            raise TargetError(f'a gaussian target takes either fan={fan!r} or x/y, not both')
        center = _fan_center(str(fan), fan_positions, fan_names)
    else:
        center = (_finite_float(parameters.pop('x', 0.0), 'gaussian x [m]'),
                  _finite_float(parameters.pop('y', 0.0), 'gaussian y [m]'))
    return GaussianTarget(center=center, **{**_GAUSSIAN_DEFAULTS, **parameters})
