"""Reading the YAML configuration into frozen dataclasses, with errors that name the key.

The shaping loop's settings (``ShapingConfig``, ``load_shaping``) live with the loop, in
``wind_shaper.control.settings``; they build on ``read_yaml`` and ``take_section`` here.
"""
from __future__ import annotations

import os
import sys
from dataclasses import fields
from pathlib import Path
from typing import Mapping

import yaml

from .errors import ConfigError
from .safe_yaml import read_yaml_file
from .geometry import TunnelGeometry


def default_config_dir() -> Path:
    """Where the shipped YAML lives: $WIND_SHAPER_CONFIG, the source tree's ``config/``, or the
    installed ``share/wind_shaper/config``."""
    env = os.environ.get('WIND_SHAPER_CONFIG')
    if env:
        return Path(env)
    source = Path(__file__).resolve().parents[2] / 'config'
    if (source / 'shaping.yaml').is_file():
        return source
    return Path(sys.prefix) / 'share' / 'wind_shaper' / 'config'


def read_yaml(path) -> dict:
    path = Path(path)
    try:
        doc = read_yaml_file(path)
    except FileNotFoundError:
        raise ConfigError(f'config file {path} does not exist') from None
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f'config file {path} is not valid YAML: {exc}') from None
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise ConfigError(f'config file {path} must hold a mapping at the top level')
    return doc


def take_section(cls, section: Mapping, where: str):
    """Build dataclass ``cls`` from ``section``, refusing unknown keys by name."""
    section = dict(section or {})
    names = {f.name for f in fields(cls)}
    unknown = set(section) - names
    if unknown:
        raise ConfigError(f'{where}: unknown keys {sorted(unknown)}; allowed: {sorted(names)}')
    try:
        return cls(**section)
    except TypeError as exc:
        raise ConfigError(f'{where}: {exc}') from None


def load_geometry(path) -> TunnelGeometry:
    return TunnelGeometry.from_config(read_yaml(path).get('tunnel', {}))


def parse_spec(text: str) -> tuple[str, dict]:
    """``name`` or ``name:key=value,key=value`` (values: numbers, lists as a/b/c, or words), the
    form of ``--hidden`` effects and workbench additions; ConfigError on an item without ``=``."""
    name, _, rest = text.partition(':')
    params = {}
    for item in filter(None, rest.split(',')):
        key, eq, value = item.partition('=')
        if not eq:
            raise ConfigError(f'{text!r}: write parameters as key=value (e.g. fan_gain[HM2]:gain=0.8)')
        parts = value.split('/')
        conv = []
        for p in parts:
            try:
                conv.append(float(p))
            except ValueError:
                conv.append(p)
        params[key.strip()] = conv[0] if len(conv) == 1 else conv
    return name.strip(), params
