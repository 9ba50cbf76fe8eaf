"""The coordinator's run folder: every iteration on disk, so a run survives restarts.

Layout of ``<root>/<name>/``::

    run.yaml                 what the run is for: first target, fan names, key points [m],
                             a snapshot of the configuration, creation time
    state.json               last completed k (-1: none), the commands for the next iteration
                             [fraction 0..1, fan order], the target in force (CLI syntax)
    model.yaml               (optional) a prior set at run time, used again on restart
    iterations/k000/
        record.json          commands before/after, step size, RMSE and predicted RMSE [N],
                             timestamps [s, Unix time], the model's formula
        sweep.npz            the raw aligned pairs: t [s], x, y [m, tunnel frame], force [N], pwm
        field.json           GP mean and std at the key points [N], coverage [m], target [N]

Every file is written to a temporary name and renamed into place. An iteration's folder is
complete before ``state.json`` is rewritten, and rewriting ``state.json`` is the last step: a
crash in the middle of an iteration leaves the previous state (and what the next start resumes
from) intact. Nothing here imports rclpy.
"""
from __future__ import annotations

import json
import os
import shutil
import time
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Optional, Sequence

import numpy as np
import yaml

from ..core.errors import RunFolderError
from ..core.limits import DEFAULT_LIMITS, Limits
from ..core.safe_yaml import read_yaml_file
from ..estimation import FieldEstimate
from ..control import IterationRecord
from ..core.tunnel import Sweep

FORMAT_VERSION = 1


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename (never half a file)."""
    tmp = path.with_name(f'.{path.name}.tmp')
    with open(tmp, 'wb') as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _atomic_write_text(path: Path, text: str) -> None:
    _atomic_write_bytes(path, text.encode())


def save_sweep(path: Path, sweep: Sweep) -> None:
    """A sweep's aligned pairs as ``.npz``: t [s], x, y [m, tunnel frame], force [N], pwm
    [fraction]; written to a temporary name and renamed."""
    tmp = path.with_name(f'.{path.name}.tmp')
    with open(tmp, 'wb') as fh:
        np.savez_compressed(fh, t=sweep.times, x=sweep.positions[:, 0], y=sweep.positions[:, 1],
                            force=sweep.forces, pwm=sweep.pwm)
    os.replace(tmp, path)


#: The arrays a sweep's ``.npz`` holds.
SWEEP_ARRAYS = ('t', 'x', 'y', 'force', 'pwm')


def load_sweep(path: Path, limits: Limits = DEFAULT_LIMITS) -> Sweep:
    """The sweep ``save_sweep`` wrote. ValueError, naming the file, when it is cut short, not an
    archive ``save_sweep`` wrote, or would unpack to more than ``limits.file_bytes``;
    OSError when it cannot be opened. Nothing in it is unpickled."""
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.infolist()
        unpacked = sum(m.file_size for m in members)
        if unpacked > limits.file_bytes:
            raise ValueError(f'{path.name} would unpack to {unpacked} bytes, more than '
                             f'{limits.file_bytes} (limits.file_bytes)')
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in SWEEP_ARRAYS if k not in z.files]
            if missing:
                raise ValueError(f'{path.name} lacks the arrays {missing}')
            return Sweep(np.column_stack([z['x'], z['y']]), z['force'], z['t'], z['pwm'])
    except (EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError) as exc:
        # a copy cut short, a disk error, another program's file: zipfile and numpy say so in
        # their own words and kinds
        raise ValueError(f'{path.name} is cut short or damaged ({type(exc).__name__}: '
                         f'{str(exc)[:80]})') from None


def folder_in(root, name: str, what: str) -> Path:
    """``root/name`` for a store's folder; RunFolderError unless ``name`` is a plain folder name."""
    if not name or Path(name).name != name or name in ('.', '..'):
        raise RunFolderError(f'{what} name {name!r} must be a plain folder name (no slashes)')
    return Path(root) / name


def _plain(value):
    """json.dumps fallback: numpy arrays and scalars as lists and numbers, anything else as text
    (an update rule's ``info`` may hold them)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return repr(value)


def _json(doc) -> str:
    return json.dumps(doc, indent=1, allow_nan=True, default=_plain)


def _floats(a) -> list:
    return [float(v) for v in np.asarray(a, dtype=float).ravel()]


@dataclass(frozen=True)
class RunInfo:
    """What a run is for (``run.yaml``). target: the first target (CLI syntax); fan_names in PWM
    order; key_points (N, 2) [m, tunnel frame]; config: a snapshot of the settings (free form)."""

    target: str
    fan_names: tuple
    key_points: np.ndarray
    config: Mapping = field(default_factory=dict)
    created_at: str = ''

    def to_yaml(self) -> str:
        doc = {'wind_shaper_run': FORMAT_VERSION, 'created_at': self.created_at,
               'target': self.target, 'fan_names': list(self.fan_names),
               'key_points_m': np.round(np.asarray(self.key_points, float), 9).tolist(),
               'config': dict(self.config)}
        return yaml.safe_dump(doc, sort_keys=False)

    @classmethod
    def from_yaml(cls, path: Path) -> 'RunInfo':
        try:
            doc = read_yaml_file(path)
            if not isinstance(doc, dict) or doc.get('wind_shaper_run') != FORMAT_VERSION:
                raise ValueError(f'not a version-{FORMAT_VERSION} run file')
            return cls(str(doc['target']), tuple(doc['fan_names']),
                       np.asarray(doc['key_points_m'], dtype=float).reshape(-1, 2),
                       doc.get('config') or {}, str(doc.get('created_at', '')))
        except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
            raise RunFolderError(f'{path} is not a readable run description ({exc}): move the '
                                 f'folder away or choose another run name') from None


def _why(exc: BaseException) -> str:
    """A short reason for a refused file: a parser's recursion by its kind only, else the
    message's first 200 characters."""
    return type(exc).__name__ if isinstance(exc, RecursionError) else str(exc)[:200]


@dataclass(frozen=True)
class RunState:
    """``state.json``: last_completed k (-1 before the first iteration), next_pwm (n_fans,)
    [fraction 0..1] for iteration last_completed + 1, and the target in force (CLI syntax)."""

    last_completed: int
    next_pwm: np.ndarray
    target: str
    updated_at: float = 0.0

    @property
    def next_k(self) -> int:
        return self.last_completed + 1

    def to_json(self) -> str:
        return _json({'last_completed': int(self.last_completed), 'next_pwm': _floats(self.next_pwm),
                      'target': self.target, 'updated_at': self.updated_at})

    @classmethod
    def from_json(cls, path: Path) -> 'RunState':
        try:
            doc = json.loads(path.read_text())
            return cls(int(doc['last_completed']), np.asarray(doc['next_pwm'], dtype=float),
                       str(doc['target']), float(doc.get('updated_at', 0.0)))
        except (OSError, ValueError, KeyError, TypeError, RecursionError) as exc:
            raise RunFolderError(f'{path} is not a readable run state ({_why(exc)}): restore it from a '
                                 f'backup or start a new run name') from None


@dataclass
class IterationData:
    """One completed iteration, as the coordinator hands it to ``RunStore.write_iteration``.

    pwm_before: commands during the sweep; pwm_after: commands for the next iteration
    [fraction, fan order]; rmse, rmse_predicted_after [N]; estimate: the field at the key points
    (core ``FieldEstimate``); target_values (N,) [N]; sweep: the raw aligned pairs; n_samples:
    pairs collected; model: the prior's formula; timestamps: named Unix times [s].
    """

    k: int
    target: str
    pwm_before: np.ndarray
    pwm_after: np.ndarray
    step_size: float
    rmse: float
    rmse_predicted_after: float
    estimate: FieldEstimate
    target_values: np.ndarray
    sweep: Sweep
    model: str = ''
    timestamps: Mapping[str, float] = field(default_factory=dict)
    info: Mapping = field(default_factory=dict)


class RunStore:
    """A run folder (see the module docstring). Open with ``RunStore.open``."""

    def __init__(self, folder: Path, info: RunInfo):
        self.folder = folder
        self.info = info

    # -- opening ------------------------------------------------------------------------------------
    @classmethod
    def open(cls, root, name: str, info: Optional[RunInfo] = None,
             initial_pwm: Optional[Sequence[float]] = None) -> 'RunStore':
        """Create ``root/name/`` (needs ``info`` and ``initial_pwm``, the commands of iteration 0)
        or reopen it. When reopening with ``info``, the folder must be for the same fans and key
        points, else ``RunFolderError`` (a run cannot continue on another tunnel)."""
        folder = folder_in(root, name, 'run')
        run_file = folder / 'run.yaml'
        if run_file.is_file():
            stored = RunInfo.from_yaml(run_file)
            if info is not None:
                cls._check_same_tunnel(folder, stored, info)
            store = cls(folder, stored)
            if not store.state_path.is_file():  # created, then crashed before the first state
                store._init_state(stored.target, initial_pwm)
            return store
        if info is None:
            raise RunFolderError(f'no run at {folder} (no run.yaml): start the coordinator with '
                                 f'this run name to create it')
        if folder.exists() and any(folder.iterdir()):
            raise RunFolderError(f'{folder} exists and is not a run folder (no run.yaml): move it '
                                 f'away or choose another run name')
        info = RunInfo(info.target, tuple(info.fan_names), np.asarray(info.key_points, float),
                       dict(info.config), info.created_at or time.strftime('%Y-%m-%dT%H:%M:%S'))
        try:
            (folder / 'iterations').mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RunFolderError(f'cannot create the run folder {folder}: {exc}') from None
        store = cls(folder, info)
        store._init_state(info.target, initial_pwm)
        _atomic_write_text(run_file, info.to_yaml())  # last: its presence marks a complete folder
        return store

    @staticmethod
    def _check_same_tunnel(folder: Path, stored: RunInfo, info: RunInfo) -> None:
        if tuple(stored.fan_names) != tuple(info.fan_names):
            raise RunFolderError(f'run folder {folder} was recorded for fans {list(stored.fan_names)}; '
                                 f'this tunnel has {list(info.fan_names)}: choose another run name')
        a, b = np.asarray(stored.key_points), np.asarray(info.key_points, float)
        if a.shape != b.shape or not np.allclose(a, b, atol=1e-6):
            raise RunFolderError(f'run folder {folder} was recorded on {len(a)} other key points '
                                 f'(this tunnel has {len(b)}): choose another run name')

    def _init_state(self, target: str, initial_pwm) -> None:
        if initial_pwm is None:
            raise RunFolderError(f'{self.state_path} is missing: reopen the run with the starting '
                                 f'commands to begin it again')
        pwm = np.asarray(initial_pwm, dtype=float)
        self._check_pwm(pwm, 'initial commands')
        self._write_state(RunState(-1, pwm, target))

    # -- paths --------------------------------------------------------------------------------------
    @property
    def state_path(self) -> Path:
        return self.folder / 'state.json'

    @property
    def model_path(self) -> Path:
        """Where a prior set at run time is kept (may not exist)."""
        return self.folder / 'model.yaml'

    def iteration_dir(self, k: int) -> Path:
        return self.folder / 'iterations' / f'k{int(k):03d}'

    # -- state --------------------------------------------------------------------------------------
    def state(self) -> RunState:
        return RunState.from_json(self.state_path)

    def last_completed(self) -> int:
        """k of the last completed iteration, -1 before the first."""
        return self.state().last_completed

    def _write_state(self, state: RunState) -> None:
        state = RunState(state.last_completed, state.next_pwm, state.target, time.time())
        _atomic_write_text(self.state_path, state.to_json())

    def set_target(self, target: str) -> RunState:
        """Make ``target`` (CLI syntax, validated by the caller) the run's target from now on."""
        st = self.state()
        new = RunState(st.last_completed, st.next_pwm, str(target))
        self._write_state(new)
        return new

    def save_model_text(self, text: str) -> Path:
        """Keep a model file set at run time (YAML text, validated by the caller)."""
        _atomic_write_text(self.model_path, text)
        return self.model_path

    def _check_pwm(self, pwm: np.ndarray, what: str) -> None:
        n = len(self.info.fan_names)
        if pwm.shape != (n,) or not np.all(np.isfinite(pwm)):
            raise RunFolderError(f'{what} must be {n} finite PWM fractions (one per fan '
                                 f'{list(self.info.fan_names)}), got {pwm.tolist()}')

    # -- iterations -----------------------------------------------------------------------------------
    def write_iteration(self, data: IterationData) -> Path:
        """Record a completed iteration and advance the state to it (the state goes last).

        ``data.k`` must be the next iteration of the run. Returns the iteration's folder."""
        state = self.state()
        if data.k != state.next_k:
            raise RunFolderError(f'iteration k={data.k} does not follow the last completed one '
                                 f'(k={state.last_completed}) of {self.folder}')
        before, after = np.asarray(data.pwm_before, float), np.asarray(data.pwm_after, float)
        self._check_pwm(before, 'pwm_before')
        self._check_pwm(after, 'pwm_after')
        est = data.estimate
        final = self.iteration_dir(data.k)
        partial = final.with_name(f'.{final.name}.partial')
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir(parents=True)
        record = {
            'k': int(data.k), 'target': data.target, 'fan_names': list(self.info.fan_names),
            'pwm_before': _floats(before), 'pwm_after': _floats(after),
            'step_size': float(data.step_size), 'rmse_N': float(data.rmse),
            'error_N2': float(data.rmse) ** 2,
            'rmse_predicted_after_N': float(data.rmse_predicted_after),
            'max_std_N': float(np.max(est.std)) if len(est.std) else float('nan'),
            'n_samples': int(len(data.sweep)), 'n_used': int(est.n_used),
            'timestamps': {k: float(v) for k, v in dict(data.timestamps).items()},
            'model': data.model, 'info': dict(data.info),
        }
        _atomic_write_text(partial / 'record.json', _json(record))
        save_sweep(partial / 'sweep.npz', data.sweep)
        _atomic_write_text(partial / 'field.json', _json({
            'mean_N': _floats(est.mean), 'std_N': _floats(est.std),
            'key_distance_m': _floats(est.key_distance), 'target_N': _floats(data.target_values),
            'n_used': int(est.n_used)}))
        if final.exists():  # left by a crash after the rename but before the state
            shutil.rmtree(final)
        os.replace(partial, final)
        self._write_state(RunState(data.k, after, data.target))
        return final

    def load_record(self, k: int) -> dict:
        """record.json of completed iteration k."""
        if not 0 <= k <= self.last_completed():
            raise RunFolderError(f'iteration k={k} is not a completed iteration of {self.folder} '
                                 f'(last completed: {self.last_completed()})')
        path = self.iteration_dir(k) / 'record.json'
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError, RecursionError) as exc:
            raise RunFolderError(f'{path} is not readable ({_why(exc)})') from None

    def load_history(self) -> list[IterationRecord]:
        """Every completed iteration as a ``control.IterationRecord`` (what
        ``wind_shaper.report.run_report.write_report`` takes), oldest first."""
        kp = np.asarray(self.info.key_points, float)
        history = []
        for k in range(self.last_completed() + 1):
            rec = self.load_record(k)
            folder = self.iteration_dir(k)
            try:
                fld = json.loads((folder / 'field.json').read_text())
                sweep = load_sweep(folder / 'sweep.npz')
            except (OSError, ValueError, KeyError, RecursionError) as exc:
                raise RunFolderError(f'{folder} is incomplete ({_why(exc)}): the run folder was edited '
                                     f'by hand or damaged') from None
            est = FieldEstimate(kp, np.asarray(fld['mean_N']), np.asarray(fld['std_N']),
                                np.asarray(fld['key_distance_m']), int(fld['n_used']))
            info = {'rmse_predicted_after_N': rec['rmse_predicted_after_N'], 'target': rec['target'],
                    'timestamps': rec['timestamps'], 'model': rec['model'], **rec['info']}
            history.append(IterationRecord(
                k=k, pwm=np.asarray(rec['pwm_before']), estimate=est,
                target=np.asarray(fld['target_N']), error=rec['error_N2'],
                next_pwm=np.asarray(rec['pwm_after']), step_size=rec['step_size'],
                sweep=sweep, info=info, settle_s=float(rec['info'].get('settle_s', 0.0))))
        return history


__all__ = ['RunStore', 'RunInfo', 'RunState', 'IterationData', 'RunFolderError']
