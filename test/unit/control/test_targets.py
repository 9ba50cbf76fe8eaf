"""Unit tests of wind_shaper.control.targets (no ROS). Points in metres, forces in newtons."""

import ast
import builtins
import math
from pathlib import Path

import numpy as np
import pytest

from wind_shaper.control import expression as targets
from wind_shaper.core.errors import TargetError
from wind_shaper.control import (
    TARGET_KINDS,
    CsvTarget,
    ExpressionTarget,
    GaussianTarget,
    ParabolicTarget,
    Target,
    UniformTarget,
    make_target,
    write_template_csv,
)

FAN_NAMES = ['LM0', 'LM1', 'LM2']
FAN_POSITIONS = np.array([[0.0, 0.0], [0.1, 0.05], [-0.1, 0.05]])


@pytest.fixture
def key_points():
    """A 3 x 3 grid of key points, 0.1 m apart [m]."""
    grid = np.array([-0.1, 0.0, 0.1])
    return np.array([(x, y) for x in grid for y in grid])


@pytest.fixture
def random_points():
    return np.random.default_rng(0).uniform(-0.5, 0.5, size=(200, 2))


# --- every target ------------------------------------------------------------------------------

def _all_targets(tmp_path, key_points):
    csv_path = write_template_csv(tmp_path / 'all.csv', key_points, np.arange(9.0))
    return [
        UniformTarget(),
        GaussianTarget(2.0, (0.1, 0.0), 0.1, base=1.5),
        ParabolicTarget(),
        ExpressionTarget('2.5 + 0.5*cos(3*theta)*r'),
        CsvTarget(csv_path, key_points),
    ]


def test_every_target_returns_finite_float64_per_point_and_describes_itself(tmp_path, key_points):
    found = _all_targets(tmp_path, key_points)
    assert {target.name for target in found} == set(TARGET_KINDS)
    for target in found:
        values = target.values(key_points)
        assert isinstance(target, Target)
        assert values.dtype == np.float64 and values.shape == (len(key_points),)
        assert np.all(np.isfinite(values))
        line = target.describe()
        assert line.startswith(f'{target.name}' if target.name != 'expr' else 'expression:')
        assert '\n' not in line and line.endswith(')' if target.name == 'csv' else ' N')
        assert repr(target).startswith(type(target).__name__ + '(')


@pytest.mark.parametrize('points', [
    [0.0, 0.0], np.zeros((4, 3)), [[0.0, np.nan]], [[0.0, np.inf]], [['a', 'b']],
    [[1.0], [2.0, 3.0]],
])
def test_every_target_rejects_bad_points(tmp_path, key_points, points):
    for target in _all_targets(tmp_path, key_points):
        with pytest.raises(TargetError, match='points'):
            target.values(points)


# --- parametric profiles -----------------------------------------------------------------------

def test_uniform_values():
    assert UniformTarget(3.0).values([[0.0, 0.0], [0.3, -0.2]]).tolist() == [3.0, 3.0]
    assert UniformTarget().force == 2.5
    assert UniformTarget(3).describe() == 'uniform: 3 N'


def test_gaussian_values_at_hand_computed_points():
    target = GaussianTarget(peak=2.0, center=(0.1, 0.0), width=0.1, base=1.5)
    points = [[0.1, 0.0], [0.2, 0.0], [0.1, 0.2], [0.0, -0.1]]
    # |z - c| = 0, 1, 2 and sqrt(2) widths
    expected = [3.5, 1.5 + 2 * math.exp(-0.5), 1.5 + 2 * math.exp(-2.0), 1.5 + 2 * math.exp(-1.0)]
    np.testing.assert_allclose(target.values(points), expected, rtol=1e-14)
    assert GaussianTarget(1.0, (0.0, 0.0), 0.5).values([[0.0, 0.0]]).tolist() == [1.0]


def test_parabolic_values_at_hand_computed_points():
    target = ParabolicTarget()
    np.testing.assert_allclose(
        target.values([[0.0, 0.0], [0.1, 0.2], [-0.3, 0.0]]), [2.25, 3.75, 4.95], rtol=1e-14)
    assert ParabolicTarget(1.0, -10.0).values([[0.0, 0.1]]).tolist() == pytest.approx([0.9])
    assert target.describe() == 'parabolic: 2.25 + 30*(x^2 + y^2) N'


@pytest.mark.parametrize('build, fragment', [
    (lambda: UniformTarget(float('nan')), 'finite'),
    (lambda: UniformTarget('abc'), 'number'),
    (lambda: UniformTarget(True), 'number'),
    (lambda: GaussianTarget(1.0, (0.0,), 0.1), 'center'),
    (lambda: GaussianTarget(1.0, (0.0, np.inf), 0.1), 'center'),
    (lambda: GaussianTarget(1.0, (0.0, 0.0), 0.0), 'width must be > 0'),
    (lambda: GaussianTarget(1.0, (0.0, 0.0), 0.1, base=None), 'base'),
    (lambda: ParabolicTarget(curvature=float('inf')), 'curvature'),
])
def test_parametric_targets_reject_bad_parameters(build, fragment):
    with pytest.raises(TargetError, match=fragment):
        build()


# --- expressions: values -----------------------------------------------------------------------

FORMULAS = [
    ('2.5 + 0.5*cos(3*atan2(y, x)) * r',
     lambda x, y: 2.5 + 0.5 * np.cos(3 * np.arctan2(y, x)) * np.hypot(x, y)),
    ('2.5 + 0.5*cos(3*theta)*r',
     lambda x, y: 2.5 + 0.5 * np.cos(3 * np.arctan2(y, x)) * np.hypot(x, y)),
    ('-x + +y - 2*x*y / 3', lambda x, y: -x + y - 2 * x * y / 3),
    ('x**2 + y**3 - 2**-1 - -x**2', lambda x, y: x ** 2 + y ** 3 - 0.5 + x ** 2),
    ('sqrt(x**2 + y**2) + exp(-r) + log(1 + r)',
     lambda x, y: np.hypot(x, y) + np.exp(-np.hypot(x, y)) + np.log(1 + np.hypot(x, y))),
    ('sin(x) + cos(y) + tan(x*y)', lambda x, y: np.sin(x) + np.cos(y) + np.tan(x * y)),
    ('abs(x) - min(x, y) + max(x, 0.1)',
     lambda x, y: np.abs(x) - np.minimum(x, y) + np.maximum(x, 0.1)),
    ('clip(10*x, -0.5, 0.5)', lambda x, y: np.clip(10 * x, -0.5, 0.5)),
    ('where(r < 0.2, 3, 1.5) + where(x >= 0, y, -y)',
     lambda x, y: np.where(np.hypot(x, y) < 0.2, 3, 1.5) + np.where(x >= 0, y, -y)),
    ('where(-0.1 <= x <= 0.1, 1, 0) + where(y > x, 2, 0) + where(y<=0, 4, 0)',
     lambda x, y: ((-0.1 <= x) & (x <= 0.1)) + 2.0 * (y > x) + 4.0 * (y <= 0)),
    ('pi*r**2 + e', lambda x, y: np.pi * (x * x + y * y) + np.e),
    ('where(1 < 2, 3, 4) + 0*x', lambda x, y: 3.0 + 0 * x),
    ('2.5', lambda x, y: np.full_like(x, 2.5)),
]


@pytest.mark.parametrize('text, formula', FORMULAS, ids=[text for text, _ in FORMULAS])
def test_expression_equals_numpy_formula(text, formula, random_points):
    x, y = random_points[:, 0], random_points[:, 1]
    values = ExpressionTarget(text).values(random_points)
    assert values.dtype == np.float64 and values.shape == (len(random_points),)
    np.testing.assert_allclose(values, formula(x, y), rtol=1e-12, atol=1e-15)


def test_expression_values_at_hand_computed_points():
    target = ExpressionTarget('2.5 + 0.5*cos(3*atan2(y, x)) * r')
    # theta = 0, pi/2, pi -> cos(3 theta) = 1, 0, -1
    np.testing.assert_allclose(
        target.values([[0.1, 0.0], [0.0, 0.2], [-0.2, 0.0]]), [2.55, 2.5, 2.4], atol=1e-15)
    assert ExpressionTarget('2**3**2').values([[0.0, 0.0]]).tolist() == [512.0]  # right-assoc.
    assert ExpressionTarget('  1 + x  ').describe() == 'expression: 1 + x N'
    assert ExpressionTarget('(1 +\n x)').describe() == 'expression: (1 + x) N'
    assert repr(ExpressionTarget('1 + x')) == "ExpressionTarget('1 + x')"


@pytest.mark.filterwarnings('error')  # numpy warnings must not leak
@pytest.mark.parametrize('text, points, fragment', [
    ('1/x', [[0.0, 0.0], [0.1, 0.0], [0.2, 0.0]], r'at 1 of 3 points, e\.g\. at \(x=0, y=0\)'),
    ('log(x)', [[0.1, 0.0], [-0.1, 0.0], [-0.2, 0.0]], r'at 2 of 3 points, e\.g\. at \(x=-0\.1'),
    ('sqrt(y)', [[0.0, -0.1]], 'at 1 of 1 points'),
    ('exp(1000*x)', [[1.0, 0.0], [0.0, 0.0]], 'at 1 of 2 points'),
    ('x/y + 1', [[0.0, 0.0]], 'at 1 of 1 points'),
])
def test_expression_non_finite_results_are_rejected(text, points, fragment):
    target = ExpressionTarget(text)
    with pytest.raises(TargetError, match=fragment):
        target.values(points)


# --- expressions: hostile and malformed input ---------------------------------------------------

HOSTILE = [
    ("__import__('os').system('echo hi')", 'attribute access'),
    ('x.__class__', r"attribute access 'x\.__class__'"),
    ('().__class__.__bases__[0]', 'subscript'),
    ('[x for x in ()]', 'list comprehension'),
    ('(x for x in ())', 'generator expression'),
    ('lambda: 1', 'lambda'),
    ('(lambda: 1)()', 'lambda'),
    ('9**9**9', r"constant part '9\*\*9\*\*9' at column 1 evaluates to inf"),
    ('10.0**400 * x', 'evaluates to inf'),
    ('(-8)**(1/3)', 'evaluates to nan'),
    ('1/0', 'evaluates to inf'),
    ("'a'", 'string literal'),
    ("b'a'", 'bytes literal'),
    ('1j', 'complex number'),
    ('True', 'boolean'),
    ('None', 'NoneType'),
    ('1e999', "number '1e999' at column 1 is not finite"),
    ('1' * 400, 'too large for float64'),
    ("open('f')", "function 'open'"),
    ("exec('1')", "function 'exec'"),
    ("eval('1')", "function 'eval'"),
    ("__import__('os')", "function '__import__'"),
    ('os', "name 'os'"),
    ('__builtins__', "name '__builtins__'"),
    ('x(1)', "name 'x' at column 1 is not a function"),
    ('(1)(2)', 'call of'),
    ('sin', 'function name'),
    ('sin(x=1)', "keyword argument 'x'"),
    ('sin(*x)', 'starred argument'),
    ('sin(x, y)', r'passes 2 argument\(s\); sin\(\) takes 1'),
    ('clip(x, 1)', r'clip\(\) takes 3'),
    ('(z := 1)', 'walrus'),
    ("f'{x}'", 'f-string'),
    ('x < 1', 'comparison'),
    ('where(x, 1, 2)', r'condition .* of where\(\) must be a comparison'),
    ('where(x == 1, 1, 2)', "comparison '=='"),
    ('x if y else 1', 'conditional expression'),
    ('x and y', "'and'/'or'"),
    ('not x', "operator 'not'"),
    ('~x', "operator '~'"),
    ('x // 2', "operator '//'"),
    ('x % 2', "operator '%'"),
    ('x @ y', "operator '@'"),
    ('{1: 2}', 'dict'),
    ('(x, y)', 'tuple'),
    ('x +', 'syntax error at column 4'),
    ('sin(x', 'syntax error at column 4'),
    ('(x\n+)', 'syntax error at line 2, column 2'),
    ('x\0', 'null byte at column 2'),
    ('', 'empty'),
    ('(' * 1000 + 'x' + ')' * 1000, r'too long \(2001 characters, at most 500\)'),
    ('+'.join(['x'] * 5000), 'too long'),
    ('sin(' * 60 + 'x' + ')' * 60, 'nested more than 50 levels'),
    ('-' * 100 + 'x', 'nested more than 50 levels'),
]
PARSE_PROBLEMS = ('syntax error', 'empty', 'NoneType', 'string literal', 'function', 'name ',
                  'attribute', 'subscript', 'lambda', 'comprehension', 'operator', 'keyword')


@pytest.mark.parametrize('text, fragment', HOSTILE, ids=[repr(text[:30]) for text, _ in HOSTILE])
def test_hostile_or_malformed_expression_is_rejected_with_a_reason(text, fragment):
    with pytest.raises(TargetError, match=fragment) as raised:
        ExpressionTarget(text)
    message = str(raised.value)
    if any(problem in message for problem in PARSE_PROBLEMS):
        assert 'allowed: numbers; names x, y' in message  # says what would have been fine
    assert len(message) < 1000


def test_shallow_nesting_is_accepted():
    value = ExpressionTarget('sin(' * 40 + 'x' + ')' * 40).values([[0.3, 0.0]])[0]
    expected = 0.3
    for _ in range(40):
        expected = math.sin(expected)
    assert value == pytest.approx(expected, rel=1e-14)


@pytest.mark.parametrize('error', [RecursionError, MemoryError])
def test_parser_exhaustion_becomes_target_error(monkeypatch, error):
    def exhausted(*args, **kwargs):
        raise error()

    monkeypatch.setattr(targets.ast, 'parse', exhausted)
    with pytest.raises(TargetError, match='too deeply nested'):
        ExpressionTarget('x')


def test_parser_nesting_limit_beyond_the_length_limit_is_a_target_error(monkeypatch):
    monkeypatch.setattr(targets, 'MAX_EXPRESSION_LENGTH', 10 ** 6)
    deep = ['(' * 1000 + 'x' + ')' * 1000, '-' * 100_000 + 'x', 'sin(' * 5000 + 'x' + ')' * 5000]
    for text in deep:
        with pytest.raises(TargetError):
            ExpressionTarget(text)


@pytest.mark.fault
def test_hostile_expressions_run_no_code(monkeypatch, tmp_path, fault_row):
    marker = tmp_path / 'pwned'
    payloads = [
        f"__import__('os').system('touch {marker}')",
        f"open('{marker}', 'w')",
        f"exec(\"open('{marker}', 'w')\")",
        f"eval(\"open('{marker}', 'w')\")",
        f"compile(\"open('{marker}', 'w')\", 'f', 'exec')",
        f"[open('{marker}', 'w') for _ in (1,)]",
        f"(lambda: open('{marker}', 'w'))()",
        f"x.__class__.__init__.__globals__['open']('{marker}', 'w')",
        f"where(x < 1, open('{marker}', 'w'), 1)",
    ]
    forbidden_calls, parses = [], []
    real_compile, real_import = builtins.compile, builtins.__import__

    def guarded_compile(source, filename, mode, flags=0, *args, **kwargs):
        if not flags & ast.PyCF_ONLY_AST:  # only parsing to an AST is fine
            forbidden_calls.append(('compile', source))
            raise AssertionError('compile() to code was called')
        parses.append(source)
        return real_compile(source, filename, mode, flags, *args, **kwargs)

    def refuse(name):
        def refused(*args, **kwargs):
            forbidden_calls.append((name, args))
            raise AssertionError(f'{name}() was called')
        return refused

    def watched_import(name, *args, **kwargs):
        if name.split('.')[0] in ('os', 'subprocess', 'shutil', 'sys', 'builtins'):
            forbidden_calls.append(('import', name))
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, 'compile', guarded_compile)
    monkeypatch.setattr(builtins, 'eval', refuse('eval'))
    monkeypatch.setattr(builtins, 'exec', refuse('exec'))
    monkeypatch.setattr(builtins, '__import__', watched_import)
    for text in payloads + [text for text, _ in HOSTILE]:
        with pytest.raises(TargetError):
            ExpressionTarget(text).values([[0.1, 0.2]])
    assert ExpressionTarget('2 + x').values([[0.5, 0.0]]).tolist() == [2.5]

    assert parses, 'the compile() guard was not exercised, so it proves nothing'
    assert forbidden_calls == []
    assert not marker.exists()
    fault_row('target expressions that try to run code (__import__, attribute access, lambdas, huge powers)',
              'parsed by an AST whitelist, refused with the reason; nothing runs', True)


def test_module_never_calls_eval_exec_or_compile():
    tree = ast.parse(Path(targets.__file__).read_text())
    called = {node.func.id for node in ast.walk(tree)
              if isinstance(node, ast.Call) and isinstance(node.func, ast.Name)}
    assert not called & {'eval', 'exec', 'compile', '__import__', 'getattr', 'globals'}


# --- CSV ----------------------------------------------------------------------------------------

def test_csv_round_trip_via_template(tmp_path, key_points):
    forces = ParabolicTarget().values(key_points) + np.pi * 1e-7 * np.arange(9)  # 17 digits
    path = write_template_csv(tmp_path / 'profile.csv', key_points, forces)
    assert path.read_text().splitlines()[0] == 'x,y,force'

    target = CsvTarget(path, key_points)
    np.testing.assert_array_equal(target.values(key_points), forces)  # exact round trip
    order = np.random.default_rng(1).permutation(len(key_points))
    np.testing.assert_array_equal(target.values(key_points[order]), forces[order])
    np.testing.assert_array_equal(target.values(key_points + 4e-4), forces)  # within tolerance
    assert 'profile.csv (9 key points, 2.25 to 2.85 N)' in target.describe()
    assert repr(target) == f"CsvTarget(path={str(path)!r}, key_points=<9 points>, tolerance=0.001)"


def test_csv_values_at_an_unknown_point_are_rejected(tmp_path, key_points):
    target = CsvTarget(write_template_csv(tmp_path / 't.csv', key_points, 2.0), key_points)
    assert target.values(key_points).tolist() == [2.0] * 9
    with pytest.raises(TargetError, match=r'1 of 2 points have no row within 0\.001 m'):
        target.values([[0.0, 0.0], [0.05, 0.0]])


def test_template_writer_rejects_mismatched_or_non_finite_values(tmp_path, key_points):
    with pytest.raises(TargetError, match=r'one force per point \(9\)'):
        write_template_csv(tmp_path / 't.csv', key_points, [1.0, 2.0])
    with pytest.raises(TargetError, match='finite'):
        write_template_csv(tmp_path / 't.csv', key_points, np.nan)


def _rows(key_points):
    """CSV lines 'x,y,force' for the key points, force = row index [N]."""
    return [f'{x!r},{y!r},{float(force)!r}' for force, (x, y) in enumerate(key_points.tolist())]


CSV_ERRORS = {
    'missing file': (None, r'does not exist: write one row per key point, e\.g\. with '
                           r'`wind-shaper targets template`'),
    'empty file': (lambda rows: '', 'is empty'),
    'wrong header': (lambda rows: '\n'.join(['x,y,f'] + rows),
                     r"has header 'x,y,f', expected 'x,y,force'"),
    'non-numeric cell': (lambda rows: '\n'.join(['x,y,force', rows[0], 'abc,0,1'] + rows[2:]),
                         r"line 3, column 'x': 'abc' is not a number"),
    'nan': (lambda rows: '\n'.join(['x,y,force'] + rows[:4] + ['0.5,0.5,nan'] + rows[5:]),
            r"line 6, column 'force' is nan: every value must be finite"),
    'inf': (lambda rows: '\n'.join(['x,y,force', '0,inf,1'] + rows[1:]), "column 'y' is inf"),
    'missing cell': (lambda rows: '\n'.join(['x,y,force', '0.0,1.0'] + rows[1:]),
                     'line 2 has 2 cells, expected 3'),
    'duplicate points': (lambda rows: '\n'.join(['x,y,force'] + rows + ['0.0,0.0005,7']),
                         r'lines 6 and 11 are the same point \(x=0, y=0\) m within 0\.001 m'),
    'too few rows': (lambda rows: '\n'.join(['x,y,force'] + rows[:8]),
                     r'CSV has 8 rows, the tunnel has 9 key points: write one row per key point, '
                     r'e\.g\. with `wind-shaper targets template`'),
    'too many rows': (lambda rows: '\n'.join(['x,y,force'] + rows + ['0.5,0.5,1']),
                      'CSV has 10 rows, the tunnel has 9 key points'),
    'points not matching': (lambda rows: '\n'.join(['x,y,force'] + rows[:8] + ['0.105,0.1,8']),
                            r'1 of 9 key points have no row within 0\.001 m, '
                            r'e\.g\. \(x=0\.1, y=0\.1\)'),
}


@pytest.mark.parametrize('case', CSV_ERRORS)
@pytest.mark.fault
def test_csv_errors(tmp_path, key_points, case, fault_row):
    build, fragment = CSV_ERRORS[case]
    path = tmp_path / 'target.csv'
    if build is not None:
        path.write_text(build(_rows(key_points)))
    with pytest.raises(TargetError, match=fragment):
        CsvTarget(path, key_points)
    fault_row('a target CSV of the wrong size, with unknown points or non-numbers',
              'refused with the line and what to fix', True)


def test_csv_accepts_blank_lines_spaces_and_a_byte_order_mark(tmp_path, key_points):
    path = tmp_path / 't.csv'
    text = '\ufeff X , y , Force \n\n' + '\n'.join(_rows(key_points)) + '\n\n'
    path.write_text(text, encoding='utf-8')
    assert CsvTarget(path, key_points).values(key_points).tolist() == list(range(9))


def test_csv_rejects_two_key_points_sharing_one_row(tmp_path):
    path = write_template_csv(tmp_path / 't.csv', [[0.0, 0.0], [0.5, 0.0]], [1.0, 2.0])
    with pytest.raises(TargetError, match=r'both match line 2: use a tolerance below half'):
        CsvTarget(path, [[0.0, 0.0], [0.0008, 0.0]], tolerance=1e-3)


def test_csv_rejects_bad_tolerance(tmp_path, key_points):
    path = write_template_csv(tmp_path / 't.csv', key_points, 1.0)
    with pytest.raises(TargetError, match='tolerance must be > 0'):
        CsvTarget(path, key_points, tolerance=0.0)


# --- factory ------------------------------------------------------------------------------------

@pytest.mark.parametrize('spec, expected', [
    ('uniform', 'UniformTarget(force=2.5)'),
    ('uniform:3.0', 'UniformTarget(force=3.0)'),
    (' Uniform : force=1 ', 'UniformTarget(force=1.0)'),
    ('gaussian', 'GaussianTarget(peak=2.0, center=(0.0, 0.0), width=0.12, base=1.5)'),
    ('gaussian:peak=2,width=0.1,x=0.1,y=0',
     'GaussianTarget(peak=2.0, center=(0.1, 0.0), width=0.1, base=1.5)'),
    ('gaussian@LM1', 'GaussianTarget(peak=2.0, center=(0.1, 0.05), width=0.12, base=1.5)'),
    ('gaussian@LM2:peak=3,base=0',
     'GaussianTarget(peak=3.0, center=(-0.1, 0.05), width=0.12, base=0.0)'),
    ('parabolic', 'ParabolicTarget(offset=2.25, curvature=30.0)'),
    ('parabolic:offset=2,curvature=25', 'ParabolicTarget(offset=2.0, curvature=25.0)'),
    ('expr:2.5 + 0.5*cos(3*atan2(y, x)) * r',
     "ExpressionTarget('2.5 + 0.5*cos(3*atan2(y, x)) * r')"),
    ({'kind': 'uniform', 'force': 1}, 'UniformTarget(force=1.0)'),
    ({'kind': 'gaussian', 'peak': 3, 'width': 0.2, 'x': -0.1},
     'GaussianTarget(peak=3.0, center=(-0.1, 0.0), width=0.2, base=1.5)'),
    ({'kind': 'gaussian', 'fan': 'LM1', 'base': 1.0},
     'GaussianTarget(peak=2.0, center=(0.1, 0.05), width=0.12, base=1.0)'),
    ({'kind': 'parabolic', 'curvature': 10}, 'ParabolicTarget(offset=2.25, curvature=10.0)'),
    ({'kind': 'expr', 'text': 'r'}, "ExpressionTarget('r')"),
])
def test_make_target(spec, expected):
    target = make_target(spec, fan_positions=FAN_POSITIONS, fan_names=FAN_NAMES)
    assert repr(target) == expected


def test_make_target_gaussian_over_a_fan_peaks_at_that_fan():
    target = make_target('gaussian@LM1', fan_positions=FAN_POSITIONS, fan_names=FAN_NAMES)
    assert target.values([[0.1, 0.05]]).tolist() == [3.5]


def test_make_target_csv_and_pass_through(tmp_path, key_points):
    path = write_template_csv(tmp_path / 't.csv', key_points, 2.0)
    from_string = make_target(f'csv:{path}', key_points=key_points)
    from_dict = make_target({'kind': 'csv', 'path': str(path), 'tolerance': 0.01},
                            key_points=key_points)
    assert from_string.values(key_points).tolist() == [2.0] * 9
    assert from_dict.tolerance == 0.01
    assert make_target(from_string) is from_string


@pytest.mark.parametrize('spec, fragment', [
    ('sphere', r"unknown target kind 'sphere'.*valid: uniform\(force\), gaussian\(peak, width"),
    ({'kind': 'sphere'}, 'valid: uniform'),
    ({'peak': 1.0}, 'needs "kind"'),
    ('gaussian:height=2', r"unknown parameter\(s\) 'height' for a gaussian target; valid: peak"),
    ({'kind': 'parabolic', 'slope': 1}, 'valid: offset, curvature'),
    ('gaussian:peak', 'key=value'),
    ('gaussian:peak=abc', r"gaussian peak \[N\] must be a number, got 'abc'"),
    ('gaussian:x=abc', r'gaussian x \[m\] must be a number'),
    ('gaussian:width=-1', 'width must be > 0'),
    ('uniform:lots', 'must be a number'),
    ('gaussian@LM9', r"no fan named 'LM9'; fans are: LM0, LM1, LM2"),
    ('gaussian@LM1:x=0.1', 'either'),
    ('uniform@LM1', 'only gaussian'),
    ('expr:', 'empty'),
    ('expr:os.system', 'attribute access'),
    ({'kind': 'expr'}, 'needs "text"'),
    ('csv:', 'needs a path'),
    ('csv:target.csv', 'key_points'),
    (42, 'string or a dict'),
])
def test_make_target_errors(spec, fragment):
    with pytest.raises(TargetError, match=fragment):
        make_target(spec, fan_positions=FAN_POSITIONS, fan_names=FAN_NAMES)


def test_make_target_fan_lookup_needs_a_consistent_fan_table():
    with pytest.raises(TargetError, match='pass fan_names and fan_positions'):
        make_target('gaussian@LM1')
    with pytest.raises(TargetError, match=r'shape \(3, 2\)'):
        make_target('gaussian@LM1', fan_names=FAN_NAMES, fan_positions=FAN_POSITIONS[:2])
