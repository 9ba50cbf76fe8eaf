"""An experiment folder: the sweeps of a designed experiment on disk, so that a crash loses none.

Layout of ``<root>/<name>/``::

    experiment.yaml          the design: where it came from, fan names, labels, commands
                             [fraction 0..1, fan order], key points [m], a configuration snapshot
    design.csv               the same design as a file ``wind-shaper collect --design`` reads
    sweeps/s000/
        sweep.npz            the stored sweep's aligned pairs: t [s], x, y [m, tunnel frame],
                             force [N], pwm [fraction]
        record.json          label, commands, coverage [0..1], pairs, sweeps it took, timestamps
                             [s, Unix time]; written last, its presence marks the row stored
        flagged-1.npz/.json  a take that missed part of the area: kept, never used as data

A row is *stored* (record.json), *flagged* (only flagged takes: sweep it again) or *pending*.
Every file is written to a temporary name and renamed into place. An ``ExperimentStore`` reads
the rows' states from the folder once, when it is opened, and keeps them up to date as it writes
rows: a status published twice a second does not read a thousand row folders each time
(``refresh`` reads them again, should another program have changed the folder). Nothing here
imports rclpy.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Optional

import numpy as np
import yaml

from ..core.errors import RunFolderError
from ..core.safe_yaml import read_yaml_file
from ..core.tunnel import Sweep
from ..experiment.design import Design, write_design
from .runstore import _atomic_write_text, _floats, _json, folder_in, load_sweep, save_sweep

FORMAT_VERSION = 1
STORED, FLAGGED, PENDING = 'stored', 'flagged', 'pending'
MARKER = 'experiment.yaml'


@dataclass(frozen=True)
class ExperimentPlan:
    """What an experiment is: ``source`` (how the design was made), ``fan_names``, ``commands``
    (S, n_fans) [fraction 0..1], ``labels`` (S,), ``key_points`` (N, 2) [m, tunnel frame],
    ``config`` (a free-form snapshot of the settings)."""

    source: str
    fan_names: tuple
    commands: np.ndarray
    labels: tuple
    key_points: np.ndarray
    config: Mapping = field(default_factory=dict)
    created_at: str = ''

    def __len__(self) -> int:
        return len(self.commands)

    def to_yaml(self) -> str:
        doc = {'wind_shaper_experiment': FORMAT_VERSION, 'created_at': self.created_at,
               'design': self.source, 'fan_names': list(self.fan_names),
               'labels': list(self.labels),
               'commands': [_floats(row) for row in np.asarray(self.commands, float)],
               'key_points_m': np.round(np.asarray(self.key_points, float), 9).tolist(),
               'config': dict(self.config)}
        return yaml.safe_dump(doc, sort_keys=False)

    @classmethod
    def from_yaml(cls, path: Path) -> 'ExperimentPlan':
        try:
            doc = read_yaml_file(path)
            if not isinstance(doc, dict) or doc.get('wind_shaper_experiment') != FORMAT_VERSION:
                raise ValueError(f'not a version-{FORMAT_VERSION} experiment file')
            names = tuple(doc['fan_names'])
            commands = np.asarray(doc['commands'], dtype=float).reshape(-1, len(names))
            return cls(str(doc['design']), names, commands, tuple(str(x) for x in doc['labels']),
                       np.asarray(doc['key_points_m'], dtype=float).reshape(-1, 2),
                       doc.get('config') or {}, str(doc.get('created_at', '')))
        except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
            raise RunFolderError(f'{path} is not a readable experiment description ({exc}): move '
                                 f'the folder away or choose another experiment name') from None


@dataclass(frozen=True)
class StoredSweep:
    """A stored row: its index in the design, label, the sweep and its record.json."""

    index: int
    label: str
    sweep: Sweep
    record: dict


class ExperimentStore:
    """An experiment folder (see the module docstring). Open with ``ExperimentStore.open``."""

    def __init__(self, folder: Path, plan: ExperimentPlan):
        self.folder, self.plan = folder, plan
        self._states: list[str] | None = None   # the rows' states, read once (``states``)

    @staticmethod
    def is_experiment(folder) -> bool:
        return (Path(folder) / MARKER).is_file()

    @classmethod
    def open(cls, root, name: str, plan: Optional[ExperimentPlan] = None) -> 'ExperimentStore':
        """Create ``root/name/`` for ``plan``, or reopen it. Reopening with a plan needs the same
        fans, key points and commands (an experiment is resumed, never silently changed);
        RunFolderError says what differs and what to do."""
        folder = folder_in(root, name, 'experiment')
        marker = folder / MARKER
        if marker.is_file():
            stored = ExperimentPlan.from_yaml(marker)
            if plan is not None:
                cls._check_same(folder, stored, plan)
            store = cls(folder, stored)
            store.refresh()
            return store
        if plan is None:
            raise RunFolderError(f'no experiment at {folder} (no {MARKER})')
        if (folder / 'run.yaml').is_file():
            raise RunFolderError(f'{folder} is a shaping run folder: give the experiment another name')
        if folder.exists() and any(folder.iterdir()):
            raise RunFolderError(f'{folder} exists and is not an experiment folder (no {MARKER}): '
                                 f'move it away or choose another name')
        plan = ExperimentPlan(plan.source, tuple(plan.fan_names), np.asarray(plan.commands, float),
                              tuple(plan.labels), np.asarray(plan.key_points, float),
                              dict(plan.config), plan.created_at or time.strftime('%Y-%m-%dT%H:%M:%S'))
        try:
            (folder / 'sweeps').mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RunFolderError(f'cannot create the experiment folder {folder}: {exc}') from None
        write_design(folder / 'design.csv', Design(plan.fan_names, plan.commands, plan.labels,
                                                   plan.source))
        _atomic_write_text(marker, plan.to_yaml())  # last: its presence marks a complete folder
        store = cls(folder, plan)
        store.refresh()
        return store

    @staticmethod
    def _check_same(folder: Path, stored: ExperimentPlan, plan: ExperimentPlan) -> None:
        resume = (f'to resume it, run the same design again (it is saved as {folder / "design.csv"});'
                  f' for another design choose another name')
        if tuple(stored.fan_names) != tuple(plan.fan_names):
            raise RunFolderError(f'experiment {folder} is for fans {list(stored.fan_names)}, this '
                                 f'request for {list(plan.fan_names)}: {resume}')
        a, b = np.asarray(stored.key_points), np.asarray(plan.key_points, float)
        if a.shape != b.shape or not np.allclose(a, b, atol=1e-6):
            raise RunFolderError(f'experiment {folder} was recorded on {len(a)} other key points '
                                 f'(this tunnel has {len(b)}): {resume}')
        c, d = np.asarray(stored.commands), np.asarray(plan.commands, float)
        if c.shape != d.shape or not np.allclose(c, d, atol=1e-9):
            raise RunFolderError(f'experiment {folder} holds another design ({len(c)} sweeps from '
                                 f'{stored.source!r}; this request: {len(d)} sweeps from '
                                 f'{plan.source!r}): {resume}')

    # -- rows -----------------------------------------------------------------------------------------
    def row_dir(self, i: int) -> Path:
        return self.folder / 'sweeps' / f's{int(i):03d}'

    def _check_row(self, i: int) -> int:
        if not 0 <= int(i) < len(self.plan):
            raise RunFolderError(f'row {i} is not a row of the {len(self.plan)}-sweep design of '
                                 f'{self.folder}')
        return int(i)

    def _flagged_takes(self, i: int) -> list[Path]:
        return sorted(self.row_dir(i).glob('flagged-*.json'),
                      key=lambda p: int(p.stem.split('-')[1]))

    def row_state(self, i: int) -> str:
        """Row ``i``'s state as the folder holds it now (read from disk)."""
        d = self.row_dir(self._check_row(i))
        if (d / 'record.json').is_file():
            return STORED
        return FLAGGED if self._flagged_takes(i) else PENDING

    def refresh(self) -> list[str]:
        """Read every row's state from the folder again (one stat per row and a listing of its
        flagged takes: about 50 ms for 1000 rows); returns them."""
        self._states = [self.row_state(i) for i in range(len(self.plan))]
        return list(self._states)

    def states(self) -> list[str]:
        """Every row's state: read from the folder when the store was opened, then kept up to
        date by ``write_sweep`` and ``write_flagged``; no disk access."""
        if self._states is None:
            return self.refresh()
        return list(self._states)

    def _mark(self, i: int, state: str) -> None:
        if self._states is not None and not (state == FLAGGED and self._states[i] == STORED):
            self._states[i] = state

    def pending(self) -> list[int]:
        """Rows still to sweep (flagged or never swept), in design order."""
        return [i for i, s in enumerate(self.states()) if s != STORED]

    def coverage(self) -> np.ndarray:
        """(S,) per row: the stored sweep's coverage, else the last flagged take's, else NaN."""
        out = np.full(len(self.plan), np.nan)
        for i in range(len(self.plan)):
            record = self.row_dir(i) / 'record.json'
            takes = self._flagged_takes(i)
            path = record if record.is_file() else (takes[-1] if takes else None)
            if path is not None:
                try:
                    value = json.loads(path.read_text()).get('coverage', np.nan)
                    out[i] = float(value)
                except (OSError, ValueError, TypeError, AttributeError, RecursionError) as exc:
                    raise RunFolderError(f'row {i} of {self.folder}: {path.name} is not readable '
                                         f'({type(exc).__name__}): move {path.parent} away to sweep '
                                         f'it again') from None
        return out

    def _info(self, i: int, sweep: Optional[Sweep], info: Mapping) -> dict:
        return {'index': i, 'label': self.plan.labels[i], 'fan_names': list(self.plan.fan_names),
                'pwm': _floats(self.plan.commands[i]),
                'n_pairs': 0 if sweep is None else int(len(sweep)),
                'written_at': time.time(), **dict(info)}

    def write_sweep(self, i: int, sweep: Sweep, info: Mapping) -> Path:
        """Store row ``i``'s sweep (its commands must be the row's) with ``info`` (coverage,
        attempts, timestamps ...). The record goes last, so a crash leaves the row pending."""
        i = self._check_row(i)
        if not np.allclose(sweep.pwm, self.plan.commands[i], atol=1e-9):
            raise RunFolderError(f'the sweep of row {i} ran at {np.round(sweep.pwm, 4).tolist()}, '
                                 f'the design says {np.round(self.plan.commands[i], 4).tolist()}')
        d = self.row_dir(i)
        d.mkdir(parents=True, exist_ok=True)
        save_sweep(d / 'sweep.npz', sweep)
        _atomic_write_text(d / 'record.json', _json(self._info(i, sweep, info)))
        self._mark(i, STORED)
        return d

    def write_flagged(self, i: int, sweep: Optional[Sweep], info: Mapping) -> Path:
        """Keep a take of row ``i`` that cannot be used (it missed part of the area): its pairs
        when there are any, and why. Returns the take's .json path."""
        i = self._check_row(i)
        d = self.row_dir(i)
        d.mkdir(parents=True, exist_ok=True)
        takes = self._flagged_takes(i)
        n = int(takes[-1].stem.split('-')[1]) + 1 if takes else 1
        if sweep is not None and len(sweep):
            save_sweep(d / f'flagged-{n}.npz', sweep)
        path = d / f'flagged-{n}.json'
        _atomic_write_text(path, _json(self._info(i, sweep, info)))
        self._mark(i, FLAGGED)
        return path

    def stored(self) -> list[StoredSweep]:
        """The stored rows, in design order."""
        out = []
        for i in range(len(self.plan)):
            d = self.row_dir(i)
            if not (d / 'record.json').is_file():
                continue
            try:
                record = json.loads((d / 'record.json').read_text())
                sweep = load_sweep(d / 'sweep.npz')
            except (OSError, ValueError, KeyError, RecursionError) as exc:
                # RecursionError: a record nested too deep for the parser (quoted by kind only)
                reason = type(exc).__name__ if isinstance(exc, RecursionError) else str(exc)[:200]
                raise RunFolderError(f'row {i} of {self.folder} is not readable ({reason}): move '
                                     f'{d} away to sweep it again') from None
            out.append(StoredSweep(i, self.plan.labels[i], sweep, record))
        return out


__all__ = ['ExperimentStore', 'ExperimentPlan', 'StoredSweep', 'STORED', 'FLAGGED', 'PENDING']
