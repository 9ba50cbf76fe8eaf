"""A designed experiment over a rig, without ROS: the logic of the coordinator's collect service.

``Experiment.open`` checks a command table against the tunnel (``experiment.check_design``: the
tunnel's fans, every command within the configured range or 0 = off, disabled fans at 0; the
whole table is refused before any fan moves) and creates its folder
(``storage.ExperimentStore``), or resumes it when the same table comes again.

``run_experiment`` sweeps every row not stored yet, in design order: ``commanding`` (the row's
commands, applied and settled) -> ``sweeping`` (the plate moves once) -> ``checking`` (the field
estimator's verdict: a sweep that missed part of the area, or has too few samples, is swept
again at the same commands and pooled, up to ``max_sweeps``) -> the row is *stored*, or
*flagged* (its takes kept, never used as data; the next call sweeps it again). A sweep with no
pairs at all (a force or pose stream is down) stops the experiment at once: every later row
would fail the same way. It awaits the same
``RigPorts`` as a shaping iteration (``coordination.iteration``), so the hardware path is the
shaping loop's. Any port may raise ``IterationStopped`` (failed or cancelled): the rows stored
before stay stored. Commands [fraction 0..1, the tunnel's fan order]; times [s].

Biasing the force sensor (``bias_zero``, opt-in; ``bias_plan`` decides per row): a strain-gauge
sensor's zero drifts over a recording, and the diagnosis sees that as a residual that follows
the recording order. ``'fans_off'`` biases the sensor on every row with every fan off, once its
fans have settled, before it is swept; ``'every_sweep'`` also turns every fan off before each
other row, waits for them to settle, biases, and then commands the row. Either zeroes a draft
that blows with every fan off, too: the fans-off sweeps then read zero, and the diagnosis can
no longer see such a draft. ``'never'`` (the default) leaves the sensor as it is.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import numpy as np

from ..core.bias import BIAS_AT_ROW, BIAS_BEFORE_ROW, BIAS_MODES, NO_BIAS, bias_plan
from ..core.config import read_yaml
from ..core.tunnel import Sweep
from ..estimation import coverage_share
from ..experiment import Design, DesignError, check_design
from ..storage import FLAGGED, PENDING, STORED, ExperimentPlan, ExperimentStore
from .iteration import FAILED, IterationStopped, RigPorts

COMMANDING, SWEEPING, CHECKING = 'commanding', 'sweeping', 'checking'


class ExperimentPorts(RigPorts, Protocol):
    """A shaping iteration's ports, and two more for an experiment's feedback."""

    def at_row(self, index: int, attempt: int) -> None:
        """The row being swept now (0-based) and its attempt (1 = first sweep)."""

    def row_done(self, index: int, outcome: str, sweep: Sweep | None, coverage: float) -> None:
        """A row was stored or flagged (``sweep``: its pairs, when there are any)."""


@dataclass(frozen=True)
class RowResult:
    """What became of one row: outcome 'stored' or 'flagged', the share of key points passed
    [0..1], the pairs kept, the sweeps it took and why it was flagged ('' when stored)."""

    index: int
    label: str
    outcome: str
    coverage: float
    n_pairs: int
    attempts: int
    message: str = ''


class Experiment:
    """A designed experiment a coordinator runs: the checked design and its folder."""

    def __init__(self, design: Design, store: ExperimentStore, radius: float):
        self.design, self.store, self.radius = design, store, float(radius)

    @classmethod
    def open(cls, setup, run_root, name: str, fan_names: Sequence[str], commands, labels,
             source: str, config_snapshot: dict | None = None) -> 'Experiment':
        """Check the table (rows of ``commands`` [fraction] in the column order ``fan_names``)
        against ``setup``'s tunnel and open its folder ``run_root/name``; DesignError or
        RunFolderError say what is wrong before anything is written or commanded."""
        geo = setup.geometry
        names = list(fan_names)
        flat = np.asarray(commands, dtype=float).ravel()
        if not names or len(flat) % len(names):
            raise DesignError(f'{len(flat)} commands do not fill rows of {len(names)} fans '
                              f'{names}: give one command per fan for every sweep')
        table = flat.reshape(-1, len(names))
        labels = [str(x) for x in labels] if len(labels) else []
        if labels and len(labels) != len(table):
            raise DesignError(f'{len(labels)} labels for {len(table)} sweeps: give one per sweep '
                              f'or none')
        labels = [lab or f'sweep {i + 1}' for i, lab in enumerate(labels or [''] * len(table))]
        bounds = setup.shaping.bounds
        design = check_design(names, table, labels, geo.fans, bounds.u_min, bounds.u_max,
                              source or 'the request')
        plan = ExperimentPlan(source or 'the request', tuple(design.fan_names), design.commands,
                              tuple(design.labels), geo.key_points,
                              {'tunnel': read_yaml(setup.config_dir / 'tunnel.yaml'),
                               'shaping': read_yaml(setup.config_dir / 'shaping.yaml'),
                               **(config_snapshot or {})})
        store = ExperimentStore.open(run_root, name, plan)
        radius = setup.shaping.make_estimator().max_gap
        return cls(design, store, radius)

    def __len__(self) -> int:
        return len(self.design)

    @property
    def folder(self):
        return self.store.folder

    def states(self) -> list[str]:
        return self.store.states()

    def pending(self) -> list[int]:
        return self.store.pending()

    def summary(self) -> str:
        states = self.states()
        flagged = [self.design.labels[i] for i, s in enumerate(states) if s == FLAGGED]
        text = f'{states.count(STORED)} of {len(states)} sweeps stored in {self.folder}'
        if flagged:
            text += (f'; flagged for a re-sweep (they missed part of the area): {", ".join(flagged)}'
                     f': call collect again with the same design to sweep them again')
        elif states.count(PENDING):
            text += f'; {states.count(PENDING)} still to sweep: call collect again with the same design'
        return text


async def run_experiment(exp: Experiment, ports: ExperimentPorts, *, max_sweeps: int,
                         clock: Callable[[], float] = time.time,
                         bias_zero: str = 'never') -> list[RowResult]:
    """Sweep every row of ``exp`` not stored yet (see the module docstring); returns what became
    of each. ``bias_zero``: when to bias the force sensor (``BIAS_MODES``). Raises
    IterationStopped when a port fails or a cancel comes: rows stored so far stay."""
    results = []
    n = len(exp)
    plan = bias_plan(exp.design.commands, bias_zero)
    for i in exp.pending():
        label, U = exp.design.labels[i], exp.design.commands[i].copy()
        where = f'sweep {i + 1} of {n} ({label})'
        stamps = {'started': clock()}
        ports.at_row(i, 0)
        if plan[i] == BIAS_BEFORE_ROW:
            ports.set_state(COMMANDING, f'{where}: every fan off to bias the force sensor')
            await ports.command_fans(np.zeros_like(U))
            await ports.bias_sensor()
            stamps['biased'] = clock()
        ports.set_state(COMMANDING, f'{where}: commanding the fans')
        await ports.command_fans(U)
        stamps['applied'] = clock()
        if plan[i] == BIAS_AT_ROW:
            await ports.bias_sensor()
            stamps['biased'] = clock()
        ports.check_boundary()
        await ports.begin_sweep()
        for attempt in range(1, max_sweeps + 1):
            ports.at_row(i, attempt)
            await ports.sweep(i, attempt)
            stamps['sweep_ended'] = clock()
            ports.check_boundary()
            ports.set_state(CHECKING, f'{where}: checking the sweep\'s coverage')
            answer = await ports.estimate(i, U)
            sweep = None if answer.sweep is None else Sweep(answer.sweep.positions, answer.sweep.forces,
                                                            answer.sweep.times, U)
            share = (coverage_share(sweep.positions, exp.store.plan.key_points, exp.radius)
                     if sweep is not None and len(sweep) else 0.0)
            info = {'coverage': share, 'attempts': attempt, 'timestamps': dict(stamps)}
            if answer.success:
                await ports.compute(exp.store.write_sweep, i, sweep, info)
                results.append(RowResult(i, label, STORED, share, len(sweep), attempt))
                ports.row_done(i, STORED, sweep, share)
                break
            if sweep is None or not len(sweep):
                # no pairs at all: a stream is down, and every further row would fail the same way
                raise IterationStopped(FAILED, f'{where}: no (force, pose) pairs: {answer.message}; '
                                       f'check the force sensor and motion-capture streams, then '
                                       f'call collect again (the stored sweeps stay)')
            if attempt == max_sweeps:
                await ports.compute(exp.store.write_flagged, i, sweep, {**info, 'message': answer.message})
                results.append(RowResult(i, label, FLAGGED, share, 0 if sweep is None else len(sweep),
                                         attempt, answer.message))
                ports.warn(f'{where} flagged for a re-sweep after {attempt} sweep(s): '
                           f'{answer.message}')
                ports.row_done(i, FLAGGED, sweep, share)
                break
            ports.warn(f'{where}: {answer.message}; sweeping again to fill the gaps '
                       f'({attempt + 1} of {max_sweeps})')
        ports.check_boundary()
    return results


__all__ = ['COMMANDING', 'SWEEPING', 'CHECKING', 'Experiment', 'ExperimentPorts', 'RowResult',
           'run_experiment', 'BIAS_MODES', 'bias_plan', 'NO_BIAS', 'BIAS_AT_ROW', 'BIAS_BEFORE_ROW']
