"""Node parameters declared from a frozen dataclass, each with a descriptor, read once.

A parameter set is a frozen dataclass whose fields carry ``param(...)`` metadata (description,
range, read-only). ``declare_parameters(node, Cls)`` declares every field on the node with its
default and descriptor and returns a ``Cls`` instance of the values in force (from the YAML
params file or the command line). Values are validated by the dataclass's ``__post_init__``.
"""
from __future__ import annotations

from dataclasses import MISSING, field, fields
from typing import Any, TypeVar

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.exceptions import ParameterException

from ..core.errors import ConfigError

T = TypeVar('T')

_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
          float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}
_ARRAY_TYPES = {float: ParameterType.PARAMETER_DOUBLE_ARRAY, int: ParameterType.PARAMETER_INTEGER_ARRAY,
                str: ParameterType.PARAMETER_STRING_ARRAY, bool: ParameterType.PARAMETER_BOOL_ARRAY}


def param(default: Any, description: str, *, low=None, high=None, read_only: bool = True,
          array_of: type | None = None):
    """A dataclass field that is a ROS parameter. ``low``/``high``: inclusive range of a number;
    ``array_of``: element type when the parameter is a list (the default must be a tuple)."""
    meta = {'description': description, 'low': low, 'high': high, 'read_only': read_only,
            'array_of': array_of}
    if isinstance(default, (list, dict)):
        raise TypeError('use a tuple for list defaults (dataclass fields must be immutable)')
    return field(default=default, metadata={'ros': meta})


def _descriptor(f, kind) -> ParameterDescriptor:
    meta = f.metadata['ros']
    d = ParameterDescriptor(name=f.name, type=kind, description=meta['description'],
                            read_only=meta['read_only'])
    low, high = meta['low'], meta['high']
    if low is not None or high is not None:
        if kind == ParameterType.PARAMETER_DOUBLE:
            d.floating_point_range = [FloatingPointRange(
                from_value=float(-1e308 if low is None else low),
                to_value=float(1e308 if high is None else high), step=0.0)]
        elif kind == ParameterType.PARAMETER_INTEGER:
            d.integer_range = [IntegerRange(from_value=int(-2**62 if low is None else low),
                                            to_value=int(2**62 if high is None else high), step=0)]
    return d


def _kind(f):
    meta = f.metadata['ros']
    if meta['array_of'] is not None:
        return _ARRAY_TYPES[meta['array_of']]
    py = f.type if isinstance(f.type, type) else {'bool': bool, 'int': int, 'float': float,
                                                  'str': str}.get(str(f.type))
    if py not in _TYPES:
        raise TypeError(f'parameter {f.name}: unsupported type {f.type!r}')
    return _TYPES[py]


def declare_parameters(node, cls: type[T], prefix: str = '') -> T:
    """Declare every ``param`` field of ``cls`` on ``node`` and return the values in force."""
    values = {}
    for f in fields(cls):
        if 'ros' not in f.metadata:
            continue
        kind = _kind(f)
        default = f.default if f.default is not MISSING else None
        if isinstance(default, tuple):
            default = list(default)
        name = prefix + f.name
        try:
            value = node.declare_parameter(name, default, _descriptor(f, kind)).value
        except ParameterException as exc:
            raise ConfigError(f'node {node.get_name()}: parameter {name!r} ({f.metadata["ros"]["description"]}) '
                              f'was given a bad value: {exc}; fix it in config/{node.get_name()}.yaml') from None
        values[f.name] = tuple(value) if isinstance(value, (list, tuple)) else value
    try:
        return cls(**values)
    except (ConfigError, ValueError, TypeError) as exc:
        raise ConfigError(f'node {node.get_name()}: invalid parameters: {exc}') from None
