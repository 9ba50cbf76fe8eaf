"""Reading the YAML configuration into frozen dataclasses, with errors that name the key."""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Mapping

import yaml

from .errors import ConfigError
from ..estimation.field import FieldEstimator
from .geometry import TunnelGeometry
from ..control.update import CommandBounds, PaperUpdate


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
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f'config file {path} does not exist') from None
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f'config file {path} is not valid YAML: {exc}') from None
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise ConfigError(f'config file {path} must hold a mapping at the top level')
    return doc


def _take(cls, section: Mapping, where: str):
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


@dataclass(frozen=True)
class ShapingConfig:
    """The loop's settings (see ``config/shaping.yaml`` for meanings and units)."""

    iterations: int = 12
    u0: float = 0.5
    u_min: float = 0.0
    u_max: float = 0.65
    samples_per_sweep: int = 1000
    update: Mapping = None
    estimator: Mapping = None
    model_file: str = 'model.yaml'

    def __post_init__(self):
        if not (isinstance(self.iterations, int) and self.iterations >= 0):
            raise ConfigError(f'shaping.iterations must be a whole number >= 0, got {self.iterations!r}')
        if not (isinstance(self.samples_per_sweep, int) and self.samples_per_sweep >= 10):
            raise ConfigError(f'shaping.samples_per_sweep must be a whole number >= 10, got '
                              f'{self.samples_per_sweep!r}')
        self.bounds  # validates u_min/u_max
        if not (self.u_min <= self.u0 <= self.u_max):
            raise ConfigError(f'shaping.u0 = {self.u0} lies outside [u_min, u_max] = '
                              f'[{self.u_min}, {self.u_max}]')

    @property
    def bounds(self) -> CommandBounds:
        return CommandBounds(float(self.u_min), float(self.u_max))

    def make_rule(self, **overrides):
        cfg = dict(self.update or {})
        cfg.update(overrides)
        method = cfg.pop('method', 'paper')
        # One section holds both methods' settings; each method drops the other's keys and
        # still refuses keys that neither knows.
        from ..control.solvers import AdaptiveUpdate
        paper_keys = {f.name for f in fields(PaperUpdate)}
        adaptive_keys = {f.name for f in fields(AdaptiveUpdate)}
        if method == 'paper':
            own = {k: v for k, v in cfg.items() if k in paper_keys or k not in adaptive_keys}
            return _take(PaperUpdate, {**own, 'bounds': self.bounds}, 'shaping.update')
        if method == 'adaptive':
            own = {k: v for k, v in cfg.items() if k in adaptive_keys or k not in paper_keys}
            if 'gain' in overrides:  # an explicit step gain (CLI --gain): the fraction of the step
                own['step_fraction'] = overrides['gain']
            return _take(AdaptiveUpdate, {**own, 'bounds': self.bounds}, 'shaping.update')
        raise ConfigError(f'shaping.update.method {method!r} is unknown; use adaptive or paper')

    def make_estimator(self) -> FieldEstimator:
        return _take(FieldEstimator, self.estimator, 'shaping.estimator')


def load_shaping(path) -> ShapingConfig:
    return _take(ShapingConfig, read_yaml(path).get('shaping', {}), f'{path}: shaping')


def load_geometry(path) -> TunnelGeometry:
    return TunnelGeometry.from_config(read_yaml(path).get('tunnel', {}))
