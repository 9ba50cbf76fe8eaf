"""Every kind of target force profile by name (``TARGET_KINDS``) and ``make_target``, which builds
one from a config string or dict: 'uniform', 'gaussian', 'parabolic' (``profiles``), 'expr'
(``expression``), 'csv' (``csv_profile``).

Units: forces [N], x, y, width [m] in the tunnel frame, tolerance [m], curvature [N/m^2].
"""

import numpy as np

from ..core.errors import TargetError
from .csv_profile import CsvTarget
from .expression import ExpressionTarget
from .profiles import GaussianTarget, ParabolicTarget, Target, UniformTarget, _finite_float

__all__ = [
    'make_target',
    'TARGET_KINDS',
]


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
