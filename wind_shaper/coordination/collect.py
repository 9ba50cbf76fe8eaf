"""A designed experiment's feedback and answer, without ROS: the bookkeeping of the
coordinator's collect service (``experiment.run_experiment`` is its procedure).

``ExperimentFeedback`` follows the experiment running: its name, the row being swept and its
attempt, the state and message, the plate poses and the live share of key points passed in this
sweep; ``status_fields`` gives the ExperimentStatus fields with the experiment's progress.
``collect_time_limit`` bounds a whole request, ``collect_answer`` words its outcome.

Times from ``clock`` (time.monotonic) [s]; progress and coverage [0..1]; positions [m].
"""
from __future__ import annotations

import math
import time
from typing import Callable

from ..estimation import Coverage
from ..storage import FLAGGED, STORED
from .experiment import CHECKING, COMMANDING, SWEEPING, Experiment
from .iteration import CANCELLED, DONE, FAILED, IDLE

#: Share of a row's progress at the start of each state.
ROW_PROGRESS = {COMMANDING: 0.0, SWEEPING: 0.1, CHECKING: 0.9}


class ExperimentFeedback:
    """What the status of a designed experiment says (see the module docstring)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self.clock = clock
        self.exp: Experiment | None = None
        self.name, self.state, self.message = '', IDLE, ''
        self.row, self.attempt, self.row_start = -1, 0, 0.0
        self._coverage: Coverage | None = None
        self.samples = 0      # plate poses received in this sweep
        self.progress = 0.0   # share of the experiment done [0..1], as last reported

    def start(self, name: str) -> None:
        """A collect request named ``name`` was accepted; its table is not read yet."""
        self.exp, self.name = None, name
        self.row, self.attempt, self.samples = -1, 0, 0
        self._coverage = None

    def opened(self, exp: Experiment) -> None:
        """The table was checked and its folder opened: coverage counts its key points."""
        self.exp = exp
        self._coverage = Coverage(exp.store.plan.key_points, exp.radius)

    def set_state(self, state: str, message: str) -> None:
        self.state, self.message = state, message
        self.row_start = self.clock()

    def on_pose(self, x: float, y: float) -> None:
        """A plate pose [m]: counted while sweeping."""
        if self._coverage is not None and self.state == SWEEPING:
            self._coverage.add((x, y))
            self.samples += 1

    def at_row(self, row: int, attempt: int) -> None:
        self.row, self.attempt = row, attempt
        if attempt <= 1 and self._coverage is not None:
            self._coverage.reset()   # re-sweeps of a row pool their samples, and their coverage
            self.samples = 0

    def where(self, row: int) -> str:
        """How messages name a row: 'sweep 3 of 12 (lhs 2)'."""
        exp = self.exp
        return f'sweep {row + 1} of {len(exp)} ({exp.design.labels[row]})' if exp else f'row {row}'

    def status_text(self) -> str:
        """'sweep 3 of 12 (lhs 2), sweeping' for messages."""
        where = self.where(self.row) if self.row >= 0 else 'starting'
        return f'{self.name}: {where}, {self.state}'

    @property
    def coverage(self) -> float:
        """Share of the key points the plate has passed in this sweep [0..1]; NaN: none yet."""
        return math.nan if self._coverage is None else float(self._coverage.share)

    def status_fields(self, sweep_duration_s: float) -> dict:
        """The ExperimentStatus fields this feedback sets (the rest keep their defaults); the
        progress counts the rows done and the share of this row's time, a sweep lasting
        ``sweep_duration_s`` [s]. Also remembered as ``progress``."""
        exp = self.exp
        msg = dict(name=self.name, state=self.state, sweep=int(self.row), attempt=int(self.attempt),
                   message=self.message, samples=int(self.samples))
        progress = 0.0
        if exp is not None:
            states = exp.states()
            msg.update(n_sweeps=len(exp), stored=states.count(STORED), flagged=states.count(FLAGGED),
                       run_folder=str(exp.folder))
            row_frac = 1.0 if self.state in (DONE, FAILED, CANCELLED) else ROW_PROGRESS.get(self.state, 0.0)
            if self.state == SWEEPING:
                frac = (self.clock() - self.row_start) / max(sweep_duration_s, 1e-3)
                row_frac = ROW_PROGRESS[SWEEPING] + 0.8 * min(max(frac, 0.0), 0.99)
            if 0 <= self.row < len(exp):
                msg['label'] = exp.design.labels[self.row]
                msg['pwm'] = [float(u) for u in exp.design.commands[self.row]]
                done = msg['stored'] + msg['flagged'] - (1 if states[self.row] != 'pending' else 0)
                progress = float(min((done + row_frac) / len(exp), 1.0))
            else:
                progress = float(msg['stored'] / len(exp)) if len(exp) else 1.0
            msg['progress'] = progress
        if self._coverage is not None:
            msg['coverage'] = float(self._coverage.share)
        self.progress = float(progress)
        return msg


def collect_time_limit(timeout_s: float, n_commands: int, n_fans: int,
                       iteration_timeout_s: float) -> float:
    """How long a collect request may take [s]: its own ``timeout_s`` when > 0, else
    ``iteration_timeout_s`` for each of its rows."""
    rows = max(n_commands // max(n_fans, 1), 1)
    return timeout_s if timeout_s > 0 else rows * iteration_timeout_s


def collect_answer(outcome: str, text: str, exp: Experiment, states: list, coverage, summary: str) -> dict:
    """The Collect response's fields once the experiment ended in ``outcome`` ('done',
    'failed', 'cancelled'; ``text``: why, when not done), from what its folder holds: each
    row's ``states`` and ``coverage`` [0..1] and the ``summary``. Success: done with every row
    stored."""
    stored = states.count(STORED)
    return dict(run_folder=str(exp.folder), labels=list(exp.design.labels), outcome=states,
                coverage=[float(c) if math.isfinite(c) else math.nan for c in coverage],
                stored=stored, success=outcome == DONE and stored == len(exp),
                message=text + summary + '; the fans are off')


__all__ = ['ROW_PROGRESS', 'ExperimentFeedback', 'collect_answer', 'collect_time_limit']
