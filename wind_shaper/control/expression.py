"""A target force profile written as an expression in x, y (``ExpressionTarget``): the text is
parsed with ``ast.parse`` and compiled against a whitelist (``ALLOWED_EXPRESSIONS``) into numpy
operations; it is never passed to eval/exec/compile.

Frame and units everywhere in this module: x, y [m] in the tunnel frame (origin on the
tunnel axis), r [m], theta [rad]; force [N], the vertical force on a 20 cm x 20 cm plate.
"""

import ast
import math

import numpy as np

from ..core.errors import TargetError
from .profiles import Target, _as_points, _point_text

__all__ = [
    'ExpressionTarget',
    'ALLOWED_EXPRESSIONS',
    'MAX_EXPRESSION_LENGTH',
    'MAX_EXPRESSION_DEPTH',
]


def _short(text, limit=60):
    return text if len(text) <= limit else text[:limit - 3] + '...'


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
