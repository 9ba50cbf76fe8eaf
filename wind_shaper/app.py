"""Session-level wiring shared by the CLI and the ROS nodes: config files -> tunnel, model,
target, loop. No argument parsing here and no rclpy."""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .control import (IterationRecord, ShapingConfig, ShapingLoop, Target, check_reachable,
                      load_shaping, make_target)
from .core.config import default_config_dir, load_geometry, parse_spec, read_yaml
from .core.geometry import TunnelGeometry
from .model import (CalibrationPlan, ModelFit, Term, collect_calibration, fit_model, load_model,
                    model_error, paper_prior, save_model)


@dataclass(frozen=True)
class Setup:
    """Everything a run needs, read from one config folder."""

    config_dir: Path
    geometry: TunnelGeometry
    shaping: ShapingConfig
    sim_config: dict

    @classmethod
    def load(cls, config_dir=None, disabled: Sequence[str] = ()) -> 'Setup':
        cdir = Path(config_dir) if config_dir else default_config_dir()
        geometry = load_geometry(cdir / 'tunnel.yaml')
        if disabled:
            geometry = geometry.with_disabled(disabled)
        sim_path = cdir / 'sim.yaml'
        sim_cfg = read_yaml(sim_path).get('sim', {}) if sim_path.is_file() else {}
        return cls(cdir, geometry, load_shaping(cdir / 'shaping.yaml'), sim_cfg)

    @property
    def model_path(self) -> Path:
        return self.config_dir / self.shaping.model_file

    def make_sim(self, seed: int | None = None, effects: Sequence = ()):
        """The simulated tunnel configured by ``sim.yaml`` (seed and extra effects overridable)."""
        from .sim import SimulatedTunnel, make_effect
        cfg = dict(self.sim_config)
        if seed is not None:
            cfg['seed'] = seed
        sim = SimulatedTunnel.from_config(self.geometry, cfg)
        if effects:
            extra = [make_effect(e) if isinstance(e, str) else e for e in effects]
            sim = sim.with_effects(list(sim.effects) + extra)
        return sim

    def load_model(self, path=None) -> Term:
        return load_model(path or self.model_path, self.geometry.fans)

    def prior_maps(self, path=None, source=None) -> tuple[tuple, str]:
        """(maps, note): the commissioning's field maps kept in the model file (``path``, or its
        text ``source``) as ``control.PastIteration``, for the adaptive update's fit, and
        why there are none where the file has maps this config cannot use (other key points);
        ((), '') when the file has none."""
        from .control import PastIteration
        from .model.modelfile import commissioning_maps_in
        maps, note = commissioning_maps_in(source if source is not None else (path or self.model_path),
                                           self.geometry.key_points, self.geometry.fans.n_fans,
                                           text=source is not None)
        return tuple(PastIteration(U, mean, std, {'commissioning': True}) for U, mean, std in maps), note

    def model_error(self, path=None) -> float:
        """The prior's calibration error per key point [N] (NaN if its file does not say)."""
        return model_error(path or self.model_path)

    def make_target(self, spec, model: Term | None = None) -> Target:
        """The target of ``spec``; with a ``model``, one the fans can plainly not deliver (per the
        model, within the command bounds) is refused with a TargetError (control.reach)."""
        fans = self.geometry.fans
        target = make_target(spec, fan_positions=fans.positions, fan_names=list(fans.names),
                             key_points=self.geometry.key_points)
        if model is not None:
            kp = self.geometry.key_points
            check_reachable(target.values(kp), kp, model, self.shaping.u_min, self.shaping.u_max,
                            fans.enabled, what=f'target {target.describe()!r}')
        return target


def hidden_effects(specs: Sequence[str]) -> list:
    """Simulator hidden effects from ``EFFECT[:key=value,...]`` texts (``weak_fan:fan=HM2,gain=0.8``,
    ``tilted_fan:fan=LM2,shift=0.04/0``; ``a/b`` is a vector), as ``--hidden`` takes them; for
    ``Setup.make_sim(effects=...)``."""
    from .sim import make_effect
    out = []
    for text in specs or ():
        name, params = parse_spec(text)
        for key, value in params.items():
            if isinstance(value, list):
                params[key] = tuple(value)
        out.append(make_effect(name, **params))
    return out


def calibrate(tunnel, fans, plan: CalibrationPlan = CalibrationPlan()) -> ModelFit:
    """Collect the paper's calibration batch on ``tunnel`` and fit the paper's prior to it."""
    data = collect_calibration(tunnel, plan)
    return fit_model(paper_prior(fans), data)


def save_fit(path, fit: ModelFit, source: str) -> Path:
    return save_model(path, fit.model, fitted_from=source, rmse_N=round(fit.rmse, 5),
                      n_samples=fit.n, fitted_at=time.strftime('%Y-%m-%dT%H:%M:%S'),
                      parameters={k: {'value': round(v['value'], 6), 'std': round(v['std'], 6)}
                                  for k, v in fit.summary()['parameters'].items()})


def shape_on_sim(setup: Setup, target_spec, *, iterations: int | None = None, seed: int = 0,
                 model: Term | None = None, u0=None, rule_overrides: dict | None = None,
                 on_iteration: Callable[[IterationRecord], None] | None = None,
                 sim=None) -> tuple[list[IterationRecord], Target]:
    """Run the shaping loop (the configured update rule; ``rule_overrides={'method': 'paper'}``
    for Algorithm 1) in-process on the simulated tunnel ``sim`` (default: ``make_sim(seed)``),
    scored against its true field."""
    loop, target = shaping_loop_on_sim(setup, target_spec, seed=seed, model=model, u0=u0,
                                       rule_overrides=rule_overrides, sim=sim)
    n = setup.shaping.iterations if iterations is None else iterations
    return loop.run(n, on_iteration), target


def shaping_loop_on_sim(setup: Setup, target_spec, *, seed: int = 0, model: Term | None = None,
                        u0=None, rule_overrides: dict | None = None, sim=None,
                        on_progress=None, model_path=None,
                        bias_zero: str = 'never') -> tuple[ShapingLoop, Target]:
    """The shaping loop of ``shape_on_sim``, not yet run. The prior's calibration error (for the
    warm start's check) and its commissioning maps are read from its model file: the setup's
    own when ``model`` is None, ``model_path`` when ``model`` came from that file, none for a
    ``model`` without a file. ``bias_zero``: when to bias the force sensor (``ShapingLoop``)."""
    sim = sim or setup.make_sim(seed=seed)
    from_file = model is None or model_path is not None
    error = setup.model_error(model_path) if from_file else float('nan')
    maps = setup.prior_maps(model_path)[0] if from_file else ()
    model = model or setup.load_model()
    target = setup.make_target(target_spec, model=model)
    kp = setup.geometry.key_points
    loop = ShapingLoop.from_settings(sim, model, target.values(kp), setup.shaping, u0=u0,
                                     rule_overrides=rule_overrides, model_error=error,
                                     truth=lambda U: sim.true_field(U, kp), prior_maps=maps,
                                     on_progress=on_progress, bias_zero=bias_zero)
    return loop, target


def format_iteration(rec: IterationRecord, names: Sequence[str]) -> str:
    """One console line: iteration, errors [N RMSE], commands [%]."""
    true = '' if rec.true_error is None else f' true {np.sqrt(rec.true_error):6.3f} N'
    pwm = ' '.join(f'{n}={100 * u:4.1f}' for n, u in zip(names, rec.pwm))
    lam = '' if rec.step_size is None else f' step {rec.step_size:.3f}'
    region = rec.info.get('region')
    where = f' (region {100 * region["share"]:.0f} %)' if region else ''
    return (f'k={rec.k:2d}  RMSE est {np.sqrt(rec.error):6.3f} N{true}{lam}  sweep {rec.plate_s:4.1f} s'
            f'{where}  PWM% {pwm}')


__all__ = ['Setup', 'hidden_effects', 'calibrate', 'save_fit', 'shape_on_sim', 'shaping_loop_on_sim',
           'format_iteration']
