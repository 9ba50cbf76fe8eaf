"""One shaping iteration over a rig, without ROS: the coordinator node's logic.

``ShapingRun`` is the run a coordinator drives: its run folder (``storage.RunStore``), the prior,
the target, the commands in force and the history the update rule learns from. It resumes a run
folder, validates a request before anything changes, turns a field estimate into the next
commands (the update rule, bounded, written to the run folder) and swaps the prior.

``run_iteration`` is the iteration's state machine (docs/graph.md): ``commanding`` -> ``sweeping``
-> ``estimating`` (sweeping again at the same commands while the estimator refuses the sweep, up
to ``max_sweeps``) -> ``updating``. It awaits a ``RigPorts`` object for everything that touches
the rig; the coordinator node implements the ports with topics and services, the unit tests with
plain asyncio. Any port may raise ``IterationStopped`` (failed or cancelled): nothing advances.

Commands U are fractions 0..1 of full PWM in the tunnel's fan order; forces [N]; key points
[m, tunnel frame]; times [s].
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable, Protocol, Sequence

import numpy as np

from ..control import PastIteration, UpdateInput
from ..control.region import RegionPlan, next_region, region_record
from ..control.warm_start import WarmStart, first_step_rule, warm_start
from ..core.bias import BIAS_AT_ROW, BIAS_BEFORE_ROW, bias_plan
from ..core.config import read_yaml
from ..core.errors import ConfigError, WindShaperError
from ..core.tunnel import Sweep
from ..estimation import FieldEstimate, closest_samples
from ..model import load_model, model_from_text
from ..model.modelfile import wiring_warning
from ..storage import IterationData, RunInfo, RunStore

# The iteration's states, as wind_shaper_msgs/IterationStatus names them (a node test checks
# that the two agree).
IDLE, COMMANDING, SWEEPING, ESTIMATING, UPDATING = 'idle', 'commanding', 'sweeping', 'estimating', 'updating'
DONE, FAILED, CANCELLED = 'done', 'failed', 'cancelled'
#: Share of an iteration's progress reached at the start of each state.
PROGRESS = {COMMANDING: 0.0, SWEEPING: 0.1, ESTIMATING: 0.8, UPDATING: 0.9, DONE: 1.0}


class IterationStopped(Exception):
    """Ends an iteration early: ``state`` is FAILED or CANCELLED, the message says why."""

    def __init__(self, state: str, message: str):
        super().__init__(message)
        self.state = state


@dataclass(frozen=True)
class FieldAnswer:
    """What the field estimator returned for one iteration: ``success`` false with ``message``
    when it refused the sweep (gaps, too few samples); else the estimate at ``key_points`` (N, 2)
    [m] (``mean``, ``std`` [N]), the aligned ``sweep`` pairs, the samples the GP used and its
    compute time [s]."""

    success: bool
    message: str = ''
    key_points: np.ndarray | None = None
    mean: np.ndarray | None = None
    std: np.ndarray | None = None
    sweep: Sweep | None = None
    n_used: int = 0
    compute_s: float = 0.0


class RigPorts(Protocol):
    """Everything an iteration needs from the rig; the coordinator node implements it."""

    def set_state(self, state: str, message: str) -> None:
        """Publish the iteration's state (and log the message)."""

    def warn(self, message: str) -> None:
        """Log a warning."""

    def check_boundary(self) -> None:
        """Between steps: raise IterationStopped on a cancel request or a passed deadline."""

    async def command_fans(self, U: np.ndarray) -> None:
        """Send U and return once the fans report it applied (and have settled)."""

    async def bias_sensor(self) -> None:
        """Zero the force sensor's reading now (only asked with every fan off and settled,
        and only with ``bias_zero`` other than 'never')."""

    async def begin_sweep(self) -> None:
        """Tell the estimator to start collecting (it keeps collecting over re-sweeps)."""

    async def sweep(self, k: int, attempt: int, plan: RegionPlan | None = None) -> None:
        """Move the plate once (or give an operator the time), over the whole area or over
        ``plan.area`` (a region sweep); raise if the fans left U."""

    async def estimate(self, k: int, U: np.ndarray, plan: RegionPlan | None = None) -> FieldAnswer:
        """Ask the estimator for the field from everything collected since begin_sweep (a
        region sweep: only ``plan.needed`` key points must have been passed)."""

    async def compute(self, fn: Callable, *args, **kwargs):
        """``fn(*args, **kwargs)``'s result: a node runs it off its executor (fitting and
        writing the run folder take long enough to hold up a cancel or the status)."""


class FanWatch:
    """The fans' read-back during one sweep: the longest pause between reports [s] and the first
    report off the commands U [fraction] by more than ``tolerance``; times from any clock [s]."""

    def __init__(self, start: float, U, tolerance: float):
        self.U, self.tolerance = np.asarray(U, dtype=float), float(tolerance)
        self.start = self.last = start
        self.longest_pause = 0.0
        self.off: tuple[float, np.ndarray] | None = None

    def saw(self, now: float, applied: np.ndarray) -> None:
        self.longest_pause = max(self.longest_pause, now - self.last)
        self.last = now
        if self.off is None and np.max(np.abs(applied - self.U)) > self.tolerance:
            self.off = (now - self.start, np.array(applied, dtype=float))

    def problem(self, now: float, timeout_s: float, fan_names: Sequence[str]) -> str:
        """Why the sweep cannot be trusted, or ''."""
        if self.off is not None:
            t, applied = self.off
            worst = int(np.argmax(np.abs(applied - self.U)))
            return (f'{t:.1f} s into the sweep the fans reported {fan_names[worst]} at '
                    f'{applied[worst]:.3f} instead of {self.U[worst]:.3f}')
        pause = max(self.longest_pause, now - self.last)
        if pause > timeout_s:
            return (f'the fans did not report their outputs for {pause:.1f} s during the sweep '
                    f'(readback_timeout_s {timeout_s:g})')
        return ''


def past_iteration(U, mean, std, info) -> PastIteration:
    """An earlier iteration as update rules see it (rules that do not learn from the run ignore
    the history)."""
    return PastIteration(np.asarray(U, float), np.asarray(mean, float), np.asarray(std, float),
                         dict(info))


class ShapingRun:
    """The run a coordinator drives, from one config folder's ``setup`` (``wind_shaper.app.Setup``
    or anything with its ``geometry``, ``shaping``, ``config_dir``, ``model_path``,
    ``load_model``, ``prior_maps`` and ``make_target``).

    State: ``k`` (next iteration), ``U`` (its commands), ``command`` (the commands in force on
    the fans: None until the first iteration of a new run), ``model`` (and ``prior_maps``, the
    commissioning's field maps its model file keeps, for the update's fit), ``target`` and
    ``target_spec``, ``last_rmse`` [N] (NaN before the first iteration), ``notes`` ((level,
    text) pairs, level 'info' or 'warning': what the opening found that an operator should read)."""

    def __init__(self, setup, store: RunStore, model, target_spec: str, target, history: list,
                 k: int, U: np.ndarray, last_completed: int, last_rmse: float, notes: list):
        geo = setup.geometry
        self.setup, self.store = setup, store
        self.fan_names = list(geo.fans.names)
        self.enabled = geo.fans.enabled
        self.key_points = geo.key_points
        self.bounds = setup.shaping.bounds
        self.model, self.target_spec, self.target = model, target_spec, target
        self.history = history
        self.k, self.U = k, U
        self.last_completed, self.last_rmse = last_completed, last_rmse
        # a resumed run holds the last completed iteration's next commands at once
        self.command: np.ndarray | None = U.copy() if last_completed >= 0 else None
        self.notes = notes
        self.last_record_folder = None  # the folder of the iteration written last
        #: the commissioning's field maps in the prior's model file, for the update's fit
        self.prior_maps: tuple = ()
        #: what the model file set last says against shaping with it ('' for nothing)
        self.model_warning = ''
        self.warm: WarmStart | None = None  # iteration 0's warm start, until it has run

    @classmethod
    def open(cls, setup, run_root, run_name: str, target_spec: str, config_snapshot: dict | None = None
             ) -> 'ShapingRun':
        """Create ``run_root/run_name`` for ``target_spec`` or resume it (its own target wins;
        the notes say so). A bad target spec raises before anything is written."""
        geo = setup.geometry
        fan_names = list(geo.fans.names)
        setup.make_target(target_spec)  # refuse a bad spec (reach is checked with the prior below)
        bounds = setup.shaping.bounds
        snapshot = dict(config_snapshot or {})
        if setup.shaping.u0 == 'warm':
            # the prior's optimum for the requested target: used only if the run is new
            warm = start_at_prior_optimum(setup, setup.load_model(), target_spec)
            u0 = warm.U
            snapshot['warm_start'] = warm.to_state()
        else:
            u0 = bounds.project(np.full(len(fan_names), float(setup.shaping.u0)), geo.fans.enabled)
        info = RunInfo(target_spec, tuple(fan_names), geo.key_points,
                       {'tunnel': read_yaml(setup.config_dir / 'tunnel.yaml'),
                        'shaping': read_yaml(setup.config_dir / 'shaping.yaml'),
                        'model_file': str(setup.model_path), **snapshot})
        store = RunStore.open(run_root, run_name, info, initial_pwm=u0)
        state = store.state()
        notes = []
        if store.model_path.is_file():
            model = load_model(store.model_path, geo.fans)
            notes.append(('info', f'prior from the run folder: {store.model_path}'))
            prior_maps, maps_note = setup.prior_maps(store.model_path)
        else:
            model = setup.load_model()
            prior_maps, maps_note = setup.prior_maps()
        if maps_note:
            notes.append(('warning', maps_note))
        model_file = store.model_path if store.model_path.is_file() else setup.model_path
        try:
            model_warning = wiring_warning(model_file.read_text(encoding='utf-8'))
        except OSError:
            model_warning = ''
        if model_warning:
            notes.append(('warning', model_warning))
        target = setup.make_target(state.target, model=model)
        if state.target != target_spec:
            notes.append(('warning', f'the run {store.folder} has target {state.target!r}; the '
                                     f'target parameter {target_spec!r} applies to new runs only '
                                     f'(a run_iteration request can change it)'))
        history = [past_iteration(r.pwm, r.estimate.mean, r.estimate.std, r.info)
                   for r in store.load_history()]
        U = bounds.project(state.next_pwm, geo.fans.enabled)
        if not np.allclose(U, state.next_pwm):
            notes.append(('warning', f'the run\'s next commands {state.next_pwm.tolist()} lie '
                                     f'outside the bounds of shaping.yaml: clipped to {U.tolist()}'))
        last = state.last_completed
        last_rmse = float(store.load_record(last)['rmse_N']) if last >= 0 else float('nan')
        run = cls(setup, store, model, state.target, target, history, state.next_k, U, last,
                  last_rmse, notes)
        run.prior_maps = prior_maps
        run.model_warning = model_warning
        stored = store.info.config.get('warm_start')
        if last < 0 and isinstance(stored, dict) and np.allclose(stored.get('U', []), U, atol=1e-9):
            run.warm = WarmStart.from_state(stored, U)
            notes.append(('info', f'iteration 0 {run.warm.text()}'))
            notes += [('warning', n) for n in run.warm.notes]
        return run

    # -- requests ---------------------------------------------------------------------------------
    def prepare(self, target_spec: str = '', step_gain: float = 0.0):
        """Validate a request before anything changes: (the new target or None, the update
        rule). Raises WindShaperError with the reason."""
        spec = target_spec.strip()
        target = self.setup.make_target(spec, model=self.model) if spec else None
        rule = self.setup.shaping.make_rule(**({'gain': float(step_gain)} if step_gain > 0 else {}))
        return target, rule

    def set_target(self, spec: str, target) -> bool:
        """Make ``target`` (validated by ``prepare``) the run's target; False if it already was."""
        if spec == self.target_spec:
            return False
        self.store.set_target(spec)
        self.target, self.target_spec = target, spec
        return True

    def model_from_text(self, text: str, source: str):
        """Build a model file's prior for the tunnel's fans and check that its Jacobian at the
        current commands is finite; ConfigError with the reason otherwise."""
        try:
            model = model_from_text(text, self.setup.geometry.fans, source=source)
        except WindShaperError as exc:
            raise ConfigError(str(exc)) from None
        J = model.jacobian(self.U, self.key_points)
        if J.shape != (len(self.key_points), len(self.fan_names)) or not np.all(np.isfinite(J)):
            raise ConfigError(f'{source}: the model\'s Jacobian at the current commands is not '
                              f'finite; check its parameters')
        return model

    def set_model(self, text: str, source: str):
        """Swap the prior for the model file ``text`` (kept in the run folder); the old one stays
        if it is refused (ConfigError)."""
        return self.adopt_model(text, self.model_from_text(text, source))

    def adopt_model(self, text: str, model):
        """Make ``model`` (built from the model file ``text`` by ``model_from_text``) the prior,
        keeping the text in the run folder."""
        self.store.save_model_text(text)
        self.model = model
        self.prior_maps, note = self.setup.prior_maps(source=text)
        if note:
            self.notes.append(('warning', note))
        self.model_warning = wiring_warning(text)
        if self.model_warning:
            self.notes.append(('warning', self.model_warning))
        return model

    # -- the update ----------------------------------------------------------------------------------
    def region_plan(self, U: np.ndarray, rule) -> RegionPlan | None:
        """Where the sweep at commands ``U`` must go: None for the whole area (the first
        iteration, region sweeps off in shaping.yaml, or too much of the field changed)."""
        if not self.history:
            return None
        return next_region(self.setup.shaping.make_sweep_length(), rule, self.model,
                           self.key_points, self.history[-1], U)

    def complete(self, k: int, U: np.ndarray, rule, answer: FieldAnswer, stamps: dict,
                 region: dict | None = None, sweeps: int = 1) -> IterationData:
        """The update rule's step from the measured field, bounded; written to the run folder
        before the run advances to k + 1 (so a crash leaves either the old or the new state).
        region: the region sweep's record (``control.region.region_record``), if it was one;
        sweeps: how many sweeps the estimate took (a refused sweep is swept again)."""
        kp = np.asarray(answer.key_points, dtype=float)
        if kp.shape != self.key_points.shape or not np.allclose(kp, self.key_points, atol=1e-9):
            raise IterationStopped(FAILED, f'the field estimator used {len(kp)} other key points '
                                   f'than the coordinator ({len(self.key_points)}): both must read '
                                   f'the same config_dir')
        mean, std = np.asarray(answer.mean, float), np.asarray(answer.std, float)
        sweep = answer.sweep
        sweep = Sweep(sweep.positions, sweep.forces, sweep.times, U)
        estimate = FieldEstimate(kp, mean, std, closest_samples(sweep, kp).key_distance,
                                 int(answer.n_used))
        target_values, model = self.target.values(kp), self.model
        warm_info, check = {}, None
        if k == 0 and self.warm is not None and not self.history:
            check = self.warm.compare(mean, std)
            warm_info = {'warm_start': {**self.warm.to_json(), 'check': check.to_json(),
                                        'check_text': check.text()}}
            rule = first_step_rule(rule, check)
        J = model.jacobian(U, kp)  # the rule's search direction and the prediction below
        step = rule.step(UpdateInput(k, U.copy(), target_values - mean, J, self.enabled, std,
                                     model=model, key_points=kp, target=target_values,
                                     history=tuple(self.history), prior_maps=self.prior_maps))
        U_next = step.U_next
        if check is not None:   # the prior's optimum not this tunnel's: start again wider
            check = self.warm.after_first_step(check, step.info.get('predicted_error'))
            warm_info['warm_start'].update(check=check.to_json(), check_text=check.text())
            U_next, restart = self.warm.next_commands(check, U_next)
            warm_info.update(restart)
        U_next = self.bounds.project(U_next, self.enabled)  # never outside the bounds
        # what the rule itself predicts at its next commands (the adaptive rule's data-corrected
        # prior); the prior's linear prediction for rules that say nothing, and for a restart
        rmse_after = float(np.sqrt(np.mean((mean + J @ (U_next - U) - target_values) ** 2)))
        if step.info.get('predicted_error') is not None and 'restart_next' not in warm_info:
            rmse_after = float(np.sqrt(step.info['predicted_error']))
        stamps['finished'] = time.time()
        data = IterationData(
            k=k, target=self.target_spec, pwm_before=U, pwm_after=U_next,
            step_size=float(step.step_size),
            rmse=float(np.sqrt(np.mean((mean - target_values) ** 2))),
            rmse_predicted_after=rmse_after,
            estimate=estimate, target_values=target_values, sweep=sweep, model=repr(model),
            timestamps=stamps, info={'gain': getattr(rule, 'gain', None),
                                     'estimator_compute_s': float(answer.compute_s),
                                     **tunnel_time(stamps), 'sweeps': int(sweeps),
                                     **dict(step.info), **warm_info,
                                     **({'region': region} if region else {})})
        self.last_record_folder = self.store.write_iteration(data)
        self.warm = None
        self.history.append(past_iteration(U, mean, std, data.info))
        self.k, self.U = k + 1, U_next.copy()
        self.last_completed, self.last_rmse = k, data.rmse
        self.command = U_next.copy()
        return data

    @staticmethod
    def done_message(data: IterationData) -> str:
        text = (f'iteration {data.k}: RMSE {data.rmse:.4f} N, predicted after the update '
                f'{data.rmse_predicted_after:.4f} N; step {data.step_size:.3f}; '
                f'{len(data.sweep)} pairs')
        if 'plate_s' in data.info:
            text += f'; tunnel time {data.info["plate_s"]:.1f} s sweeping, {data.info["settle_s"]:.1f} s settling'
        if data.info.get('region'):
            text += f'; {data.info["region"]["text"]}'
        check = data.info.get('warm_start', {}).get('check_text')
        if check:
            text += ('; WARNING: ' if data.info['warm_start']['check']['mismatch'] else '; ') + check
        ridge = data.info.get('ridge')
        if ridge:
            start = max(float(ridge['start']), 1e-12)
            text += (f'; the step stays on this side of a ridge the fitted model shows (a dip in the fans\' '
                     f'curves): on the way to a field {1 - ridge["end"] / start:.0%} better it predicts one '
                     f'{ridge["height"] / start:.1f} x worse than now')
        if data.info.get('stop'):
            text += f'; the update rule advises stopping: {data.info.get("stop_reason", "")}'
        return text


def start_at_prior_optimum(setup, model, target_spec: str) -> WarmStart:
    """The warm start of a new run: the prior's bounded optimum for ``target_spec``, with the
    prior's calibration error from its model file."""
    geo = setup.geometry
    target = setup.make_target(target_spec)
    rule = setup.shaping.make_rule()
    return warm_start(model, geo.key_points, target.values(geo.key_points), setup.shaping.bounds,
                      geo.fans.enabled, fan_names=geo.fans.names, model_error=setup.model_error(),
                      idle_below=getattr(rule, 'idle_below', 0.0))


def tunnel_time(stamps: dict) -> dict:
    """An iteration's tunnel time from its stamps [s]: fans commanded until the sweep began
    (the fans reporting the commands, settle_s, the estimator's begin) and the sweeps (the
    plate's time, re-sweeps included)."""
    out = {}
    if 'started' in stamps and 'sweep_started' in stamps:
        out['settle_s'] = round(max(0.0, stamps['sweep_started'] - stamps['started']), 3)
    if 'sweep_started' in stamps and 'sweep_ended' in stamps:
        out['plate_s'] = round(max(0.0, stamps['sweep_ended'] - stamps['sweep_started']), 3)
    return out


async def run_iteration(run: ShapingRun, ports: RigPorts, rule, *, max_sweeps: int,
                        clock: Callable[[], float] = time.time, bias_zero: str = 'never') -> IterationData:
    """One iteration of ``run`` on the rig behind ``ports`` (see the module docstring); returns
    what was written to the run folder. ``bias_zero`` (``core.bias.BIAS_MODES``): 'every_sweep'
    turns every fan off, biases the force sensor once they settled and then commands the
    iteration (a drifting zero would otherwise move every map of the run). Raises
    IterationStopped when it fails or is cancelled: the run then stays at its iteration and the
    fans at the last completed commands."""
    k, U = run.k, run.U.copy()
    stamps = {'started': clock()}
    bias = bias_plan(U, bias_zero)[0]
    # 1. commanding (after a bias with every fan off, when asked). ``run.command`` is what the
    # node publishes to the fans, so it is set to each command before the port waits for it.
    if bias == BIAS_BEFORE_ROW:
        ports.set_state(COMMANDING, f'iteration {k}: every fan off to bias the force sensor')
        run.command = np.zeros_like(U)
        await ports.command_fans(run.command)
        await ports.bias_sensor()
        stamps['biased'] = clock()
        ports.check_boundary()
    ports.set_state(COMMANDING, f'iteration {k}: commanding the fans')
    run.command = U
    await ports.command_fans(U)
    stamps['applied'] = clock()
    if bias == BIAS_AT_ROW:
        await ports.bias_sensor()
        stamps['biased'] = clock()
    ports.check_boundary()

    # 2. sweeping, 3. estimating: the estimator refuses a sweep that missed part of the area or
    # has too few samples, and keeps collecting; sweep again at the same commands and estimate
    # on all of it. With region sweeps on, only the region the last step changed is swept and
    # the rest carried over (control.region).
    plan = await ports.compute(run.region_plan, U, rule)
    await ports.begin_sweep()
    stamps['sweep_started'] = clock()
    for attempt in range(1, max_sweeps + 1):
        await ports.sweep(k, attempt, plan)
        stamps['sweep_ended'] = clock()
        ports.check_boundary()
        ports.set_state(ESTIMATING, f'iteration {k}: estimating the field')
        answer = await ports.estimate(k, U, plan)
        if answer.success:
            break
        if attempt == max_sweeps:
            raise IterationStopped(FAILED, f'no field estimate after {attempt} sweep(s): '
                                   f'{answer.message}')
        ports.warn(f'iteration {k}: {answer.message}; sweeping again to fill the gaps '
                   f'({attempt + 1} of {max_sweeps})')
    stamps['estimated'] = clock()
    ports.check_boundary()

    region = {}
    if plan is not None:
        region = region_record(plan, plan.consistency(answer.mean, answer.std))
        mean, std = plan.fuse(answer.mean, answer.std)
        answer = replace(answer, mean=mean, std=std)

    # 4. updating
    ports.set_state(UPDATING, f'iteration {k}: updating the commands')
    return await ports.compute(run.complete, k, U, rule, answer, stamps, region=region,
                               sweeps=attempt)


__all__ = ['IDLE', 'COMMANDING', 'SWEEPING', 'ESTIMATING', 'UPDATING', 'DONE', 'FAILED',
           'CANCELLED', 'PROGRESS', 'IterationStopped', 'FieldAnswer', 'RigPorts', 'FanWatch',
           'ShapingRun', 'past_iteration', 'run_iteration', 'start_at_prior_optimum', 'tunnel_time']
