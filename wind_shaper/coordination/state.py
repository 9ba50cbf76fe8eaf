"""What the coordinator node keeps between its callbacks, and what it reports, without ROS.

``CoordinatorState`` holds the bookkeeping of one coordinator: whether a procedure (an
iteration, a designed experiment or a held-plate point) runs, the commands in force (the run's,
or those an experiment holds), the fans' last read-back, the iteration's state and progress, the
live sweep figures (samples, coverage, largest std) and whether the last iteration failed. It
turns them into the fields of the iteration status and of the diagnostics, and into the words
of a refusal while something runs. The node holds its lock around every call that changes or
reads the state from more than one callback.

Commands [fraction 0..1, the tunnel's fan order]; times from ``clock`` (time.monotonic) [s];
forces and std [N]; coverage [0..1].
"""
from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from .iteration import FAILED, IDLE, PROGRESS, SWEEPING, FanWatch, ShapingRun

#: IterationStatus.state while a designed experiment (collect) runs.
COLLECTING = 'collecting'


class CoordinatorState:
    """The coordinator's bookkeeping for ``run`` (see the module docstring). Sweeps last
    ``sweep_duration_s`` [s] unless a procedure asks for another length."""

    def __init__(self, run: ShapingRun, sweep_duration_s: float,
                 clock: Callable[[], float] = time.monotonic):
        self.run, self.clock = run, clock
        self.default_sweep_s = float(sweep_duration_s)
        self.sweep_duration_s = self.default_sweep_s   # of the procedure running [s]
        self.running = False
        self.held: np.ndarray | None = None     # commands an experiment holds (then: off)
        self.applied: np.ndarray | None = None  # the fans' last read-back
        self.applied_at: float | None = None    # clock() of the last read-back
        self.fan_watch: FanWatch | None = None  # the read-back during a sweep
        self.state, self.message, self.progress = IDLE, '', 0.0
        self.phase_start = clock()
        self.samples, self.counting = 0, False  # plate poses of this sweep; counting them now
        self.coverage = self.max_std = math.nan
        self.last_failed = False
        self.status_k = run.last_completed      # the iteration the status is about

    # -- the commands in force ----------------------------------------------------------------------
    def command_in_force(self) -> np.ndarray | None:
        """What the fans are told now: an experiment's row (or off after one), else the run's."""
        return self.held if self.held is not None else self.run.command

    def hold(self, U) -> None:
        """Hold the commands ``U`` (an experiment's row, or off after it) until an iteration
        begins."""
        self.held = np.asarray(U, dtype=float).copy()

    def saw_applied(self, applied: np.ndarray) -> None:
        """The fans reported ``applied``; a sweep being watched takes note of it too."""
        self.applied, self.applied_at = applied, self.clock()
        watch = self.fan_watch
        if watch is not None:
            watch.saw(self.clock(), applied)

    def applied_since(self, since: float, U: np.ndarray, tolerance: float) -> bool:
        """True when a read-back that arrived at or after ``since`` matches ``U`` within
        ``tolerance``. A read-back kept from before (a fan_output that has since restarted and
        ramps from safe) proves nothing."""
        A, at = self.applied, self.applied_at
        return (A is not None and at is not None and at >= since
                and np.max(np.abs(A - U)) <= tolerance)

    def not_applied_text(self, U: np.ndarray, timeout_s: float, tolerance: float, topic: str) -> str:
        """Why commanding failed: the fans did not report ``U`` on ``topic`` within ``timeout_s``."""
        got = 'nothing' if self.applied is None else np.round(self.applied, 4).tolist()
        return (f'the fans did not report the commands {np.round(U, 4).tolist()} applied within '
                f'{timeout_s:g} s (tolerance {tolerance:g}; last read-back: {got} on {topic}): is '
                f'fan_output running and the autopilot connected?')

    # -- procedures ----------------------------------------------------------------------------------
    def begin(self, sweep_duration_s: float) -> None:
        """A procedure starts: its sweeps last ``sweep_duration_s`` (<= 0: the default) [s]."""
        self.running = True
        self.sweep_duration_s = sweep_duration_s if sweep_duration_s > 0 else self.default_sweep_s

    def end(self) -> None:
        self.running = False
        self.counting = False

    def busy(self, cancel_service: str, experiment: str = '', holding: bool = False) -> str:
        """'' when idle, else why a new request must wait: ``experiment`` is the running
        experiment's status text ('' when none runs), ``holding`` a held-plate point is being
        recorded; ``cancel_service`` is the resolved name of the cancel service."""
        if not self.running:
            return ''
        wait = f'wait for it or cancel it (`wind-shaper cancel`, or call {cancel_service})'
        if experiment:
            return f'an experiment is running ({experiment}): {wait}'
        if holding:
            return f'a held-plate point is being recorded: {wait}'
        return f'an iteration is running (k={self.run.k}, {self.state}): {wait}'

    def cancel_text(self, experiment: str = '') -> str:
        """What a cancel request is told while a procedure runs (``experiment``: the running
        experiment's status text, '' for an iteration or a point)."""
        if experiment:
            return (f'cancelling the experiment ({experiment}) at the next step boundary; the '
                    f'sweeps stored so far stay and the fans go off')
        return (f'cancelling iteration {self.run.k} ({self.state}) at the next step boundary; the '
                f'fans keep the last completed iteration\'s commands')

    # -- the iteration's state -------------------------------------------------------------------------
    def enter(self, state: str, message: str) -> None:
        """The iteration enters ``state``; its progress jumps to the state's share."""
        self.state, self.message = state, message
        self.phase_start = self.clock()
        self.progress = PROGRESS.get(state, self.progress)

    def start_iteration(self, k: int) -> None:
        self.samples, self.status_k = 0, k

    def sweep_begun(self) -> None:
        """The estimator cleared its buffers: no samples, coverage or std yet."""
        self.samples = 0
        self.coverage = self.max_std = math.nan

    def count_pose(self) -> bool:
        """A plate pose arrived; True when it counts (a sweep is being recorded)."""
        if self.counting:
            self.samples += 1
        return self.counting

    def stopped(self, state: str) -> None:
        """An iteration ended early in ``state``: a failure shows in the diagnostics."""
        self.last_failed = state == FAILED

    # -- reports ---------------------------------------------------------------------------------------
    def status_fields(self, fan_names: list, experiment=None) -> dict:
        """The IterationStatus fields (all but the header). ``experiment`` (a running
        experiment's ``ExperimentFeedback``, or None): the status then says so, with its row and
        progress, rather than the idle state or the last iteration's outcome. While sweeping
        the progress moves on with the time spent."""
        run = self.run
        state, message, progress = self.state, self.message, self.progress
        samples, coverage, max_std = self.samples, self.coverage, self.max_std
        if experiment is not None:
            state, message, progress = (COLLECTING, f'experiment {experiment.status_text()}'
                                        + (f': {experiment.message}' if experiment.message else ''),
                                        experiment.progress)
            samples, coverage, max_std = experiment.samples, experiment.coverage, math.nan
        elif self.state == SWEEPING and self.running:
            frac = (self.clock() - self.phase_start) / self.sweep_duration_s
            span = PROGRESS['estimating'] - PROGRESS['sweeping']
            progress = PROGRESS['sweeping'] + span * min(max(frac, 0.0), 0.99)
        U = self.command_in_force()
        U = U if U is not None else run.U
        return dict(iteration=int(self.status_k), state=state, progress=float(progress),
                    samples=int(samples), message=message, coverage=float(coverage),
                    max_std=float(max_std), target=run.target_spec, fan_names=fan_names,
                    pwm=[float(u) for u in U], rmse=float(run.last_rmse),
                    run_folder=str(run.store.folder))

    def diagnostics(self, fan_names: list, collecting: bool) -> tuple[bool, str, dict]:
        """(a warning: the last iteration failed, the message, the key values) for /diagnostics."""
        run, U = self.run, self.command_in_force()
        values = {'state': COLLECTING if collecting else self.state,
                  'next_iteration': run.k, 'target': run.target_spec,
                  'rmse_N': run.last_rmse, 'run_folder': str(run.store.folder),
                  'commands': 'none yet' if U is None
                  else ' '.join(f'{n}={u:.4f}' for n, u in zip(fan_names, U)),
                  'prior': repr(run.model)}
        message = f'{self.state}: {self.message}' if self.message else self.state
        return self.last_failed, message, values


__all__ = ['COLLECTING', 'CoordinatorState']
