"""The shaping loop's settings: ``shaping.yaml``'s ``shaping`` section (``ShapingConfig``), which
builds the update rule and the field estimator the loop runs with.

Commands [fraction 0..1 of full PWM]; see ``config/shaping.yaml`` for every key's meaning and unit.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Mapping

from ..core.config import read_yaml, take_section
from ..core.errors import ConfigError
from ..estimation import FieldEstimator
from ..model.length_scale import footprint_length_scale
from .adaptive import AdaptiveUpdate
from .sweep_length import SweepLength
from .update import CommandBounds, PaperUpdate


@dataclass(frozen=True)
class ShapingConfig:
    """The loop's settings (see ``config/shaping.yaml`` for meanings and units)."""

    iterations: int = 12
    u0: float | str = 'warm'
    u_min: float = 0.0
    u_max: float = 0.65
    samples_per_sweep: int = 1000
    fan_settle_s: float = 2.0
    sweep: Mapping = None
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
        if isinstance(self.u0, str):
            if self.u0 != 'warm':
                raise ConfigError(f"shaping.u0 must be 'warm' (start at the prior's optimum) or a "
                                  f'command in [u_min, u_max]; got {self.u0!r}')
        elif isinstance(self.u0, bool) or not isinstance(self.u0, (int, float)):
            raise ConfigError(f"shaping.u0 must be 'warm' or a number; got {self.u0!r}")
        elif not (self.u_min <= self.u0 <= self.u_max):
            raise ConfigError(f'shaping.u0 = {self.u0} lies outside [u_min, u_max] = '
                              f'[{self.u_min}, {self.u_max}]')
        if not (isinstance(self.fan_settle_s, (int, float)) and 0 <= self.fan_settle_s <= 600):
            raise ConfigError(f'shaping.fan_settle_s must be 0..600 s; got {self.fan_settle_s!r}')
        self.make_sweep_length()  # validates the sweep section

    @property
    def bounds(self) -> CommandBounds:
        return CommandBounds(float(self.u_min), float(self.u_max))

    def make_rule(self, **overrides):
        cfg = dict(self.update or {})
        cfg.update(overrides)
        method = cfg.pop('method', 'paper')
        # One section holds both methods' settings; each method drops the other's keys and
        # still refuses keys that neither knows.
        paper_keys = {f.name for f in fields(PaperUpdate)}
        adaptive_keys = {f.name for f in fields(AdaptiveUpdate)}
        if method == 'paper':
            own = {k: v for k, v in cfg.items() if k in paper_keys or k not in adaptive_keys}
            return take_section(PaperUpdate, {**own, 'bounds': self.bounds}, 'shaping.update')
        if method == 'adaptive':
            own = {k: v for k, v in cfg.items() if k in adaptive_keys or k not in paper_keys}
            if 'gain' in overrides:  # an explicit step gain (CLI --gain): the fraction of the step
                own['step_fraction'] = overrides['gain']
            return take_section(AdaptiveUpdate, {**own, 'bounds': self.bounds}, 'shaping.update')
        raise ConfigError(f'shaping.update.method {method!r} is unknown; use adaptive or paper')

    def make_sweep_length(self) -> SweepLength:
        return take_section(SweepLength, self.sweep, 'shaping.sweep')

    def make_estimator(self, model=None) -> FieldEstimator:
        """The field estimator of the ``estimator`` section. Its ``max_length_scale`` is a length
        [m], ``none``, or ``footprint`` (the default): the length the fans' footprints in the
        prior ``model`` (a model ``Term``) imply (``model.length_scale``); without a model
        (callers that only read the estimator's coverage settings) no bound."""
        cfg = dict(self.estimator or {})
        limit = cfg.pop('max_length_scale', 'footprint')
        if limit == 'footprint':
            cfg['max_length_scale'] = footprint_length_scale(model) if model is not None else None
        elif limit in (None, 'none'):
            cfg['max_length_scale'] = None
        elif isinstance(limit, (int, float)) and not isinstance(limit, bool):
            cfg['max_length_scale'] = limit
        else:
            raise ConfigError(f'shaping.estimator.max_length_scale must be footprint, none or a '
                              f'length [m]; got {limit!r}')
        return take_section(FieldEstimator, cfg, 'shaping.estimator')


def load_shaping(path) -> ShapingConfig:
    return take_section(ShapingConfig, read_yaml(path).get('shaping', {}), f'{path}: shaping')
