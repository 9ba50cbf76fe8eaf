"""Data sets of sweeps: where they come from, how they are split, what a fit sees.

A ``SweepSet`` is several sweeps of the force plate, each at its own fan commands (positions
[m, tunnel frame], forces [N], commands [fraction 0..1]). Sources, all returning a SweepSet:

* ``from_sim``: run sweeps on a simulated (or any ``core.tunnel.Tunnel``) tunnel at commands
  from ``design_commands``;
* ``from_bag``: a rosbag2 recording of the node graph (``wind_shaper.bag.read_sweeps``);
* ``from_run_folder``: the coordinator's run folder (``wind_shaper.storage.runstore.RunStore``);
* ``from_experiment``: an experiment folder of ``wind-shaper collect`` (``storage.ExperimentStore``);
* ``from_report``: the report folder of ``wind-shaper shape`` (``run.json`` + ``sweeps.npz``);
* ``load_sweeps``: any of the paths above, told apart by what the path holds.

Held-out evaluation always splits by sweep (``SweepSet.split``): samples of one sweep share its
turbulence and path, so splitting samples would grade a model on data it has in effect seen.

A fit sees ``FitData``: each sweep reduced to cell means on a square grid (``cell`` [m]; the
default 3 cm is the key-point spacing), which keeps the fits fast and averages the turbulence,
with the sweep each cell came from so that metrics can be given per sweep.
"""
from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..core.tunnel import Measurements, Sweep
from ..experiment.design import design_commands
from ..model.memo import freeze
from .errors import DataSourceError

__all__ = ['SweepSet', 'FitData', 'design_commands', 'from_sim', 'from_bag', 'from_run_folder',
           'from_experiment', 'from_report', 'load_sweeps']


@dataclass(frozen=True)
class FitData:
    """What a fit sees. U (M, n_fans) commands [fraction]; Z (M, 2) plate centres [m]; y (M,)
    forces [N]; sweep (M,) index of the sweep each row came from (-1: not from a sweep, e.g. a
    calibration batch); count (M,) raw samples averaged into each row."""

    U: np.ndarray
    Z: np.ndarray
    y: np.ndarray
    sweep: np.ndarray
    count: np.ndarray

    def __post_init__(self):
        # read-only arrays: the model's geometry cache (model.memo) may then keep what it
        # computes from them through a fit's many evaluations
        for name in ('U', 'Z', 'y', 'sweep', 'count'):
            object.__setattr__(self, name, freeze(getattr(self, name)))

    def __len__(self) -> int:
        return len(self.y)

    def subset(self, mask) -> 'FitData':
        """Rows picked by a boolean mask, an index array or a slice."""
        if not isinstance(mask, slice):
            mask = np.asarray(mask)
        return FitData(self.U[mask], self.Z[mask], self.y[mask], self.sweep[mask], self.count[mask])

    @classmethod
    def from_measurements(cls, m: Measurements) -> 'FitData':
        """Held-plate data (e.g. the calibration batch): one row per measurement."""
        ok = np.all(np.isfinite(m.pwm), 1) & np.all(np.isfinite(m.positions), 1) & np.isfinite(m.forces)
        n = int(ok.sum())
        return cls(m.pwm[ok], m.positions[ok], m.forces[ok], np.full(n, -1), np.ones(n, int))

    @staticmethod
    def concatenate(parts: Sequence['FitData']) -> 'FitData':
        return FitData(np.vstack([p.U for p in parts]), np.vstack([p.Z for p in parts]),
                       np.concatenate([p.y for p in parts]), np.concatenate([p.sweep for p in parts]),
                       np.concatenate([p.count for p in parts]))


def _bin_sweep(sweep: Sweep, cell: float | None, index: int) -> FitData:
    clean = sweep.finite()
    n = len(clean)
    if n == 0:
        return FitData(np.zeros((0, len(sweep.pwm))), np.zeros((0, 2)), np.zeros(0),
                       np.zeros(0, int), np.zeros(0, int))
    if cell is None:
        return FitData(np.tile(clean.pwm, (n, 1)), clean.positions, clean.forces,
                       np.full(n, index), np.ones(n, int))
    ij = np.floor(clean.positions / cell).astype(np.int64)
    _, inverse, counts = np.unique(ij, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    k = len(counts)
    Z = np.zeros((k, 2))
    np.add.at(Z, inverse, clean.positions)
    y = np.bincount(inverse, weights=clean.forces, minlength=k)
    Z /= counts[:, None]
    y /= counts
    return FitData(np.tile(clean.pwm, (k, 1)), Z, y, np.full(k, index), counts)


@dataclass(frozen=True)
class SweepSet:
    """Sweeps at different commands. sweeps: the core ``Sweep`` objects; fan_names: the fan
    order of every ``sweep.pwm``; source: where they came from (for reports); labels: one name
    per sweep (``sim#3``, ``bag k=2``, ``run k=5``)."""

    sweeps: tuple
    fan_names: tuple
    source: str = ''
    labels: tuple = field(default=())

    def __post_init__(self):
        sweeps = tuple(self.sweeps)
        names = tuple(self.fan_names)
        for i, s in enumerate(sweeps):
            if len(s.pwm) != len(names):
                raise DataSourceError(f'sweep {i} has {len(s.pwm)} commands but the data set is for '
                                      f'{len(names)} fans {list(names)}')
        labels = tuple(self.labels) or tuple(f'#{i}' for i in range(len(sweeps)))
        if len(labels) != len(sweeps):
            raise DataSourceError(f'{len(labels)} labels for {len(sweeps)} sweeps')
        object.__setattr__(self, 'sweeps', sweeps)
        object.__setattr__(self, 'fan_names', names)
        object.__setattr__(self, 'labels', labels)

    def __len__(self) -> int:
        return len(self.sweeps)

    def __getitem__(self, index) -> 'SweepSet':
        """A sub-set: an int, a slice or a sequence of sweep indices."""
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        picks = range(len(self))[index] if isinstance(index, slice) else [int(i) for i in index]
        return SweepSet(tuple(self.sweeps[i] for i in picks), self.fan_names, self.source,
                        tuple(self.labels[i] for i in picks))

    def __add__(self, other: 'SweepSet') -> 'SweepSet':
        if tuple(other.fan_names) != tuple(self.fan_names):
            raise DataSourceError(f'cannot pool sweeps for fans {list(self.fan_names)} and '
                                  f'{list(other.fan_names)}')
        source = self.source if self.source == other.source else f'{self.source} + {other.source}'
        return SweepSet(self.sweeps + other.sweeps, self.fan_names, source, self.labels + other.labels)

    @property
    def commands(self) -> np.ndarray:
        """(n_sweeps, n_fans) commands of each sweep [fraction]."""
        return np.array([s.pwm for s in self.sweeps], dtype=float).reshape(len(self), len(self.fan_names))

    @property
    def n_samples(self) -> int:
        return int(sum(len(s) for s in self.sweeps))

    def command_spread(self, enabled: Sequence[bool] | None = None) -> dict:
        """How much the fans' commands vary across the sweeps: per fan, the interquartile range
        of its command over the sweeps (the width of the middle half of its commands [fraction of
        full PWM]; one odd sweep, such as a run's start, does not count), and ``median``: the
        median over the ``enabled`` fans (default: fans with any command above 0).

        A Latin-hypercube design over [0, 0.9] (``design_commands``) gives about 0.45; the sweeps
        of a shaping run that has converged, a few hundredths. Per-fan effects need the
        commands to vary: at one operating point a term that patches the residual there fits
        the held-out sweeps too (they share the commands) without being the physics."""
        U = self.commands
        if enabled is None:
            enabled = np.any(U > 0, axis=0) if len(U) else np.ones(U.shape[1], bool)
        enabled = np.asarray(enabled, bool)
        if len(U) == 0 or not enabled.any():
            return {'per_fan': {}, 'median': 0.0}
        q25, q75 = np.percentile(U, [25, 75], axis=0)
        iqr = q75 - q25
        return {'per_fan': {n: float(v) for n, v, e in zip(self.fan_names, iqr, enabled) if e},
                'median': float(np.median(iqr[enabled]))}

    def split(self, test_fraction: float = 1 / 3, test: Sequence[int] | None = None
              ) -> tuple['SweepSet', 'SweepSet']:
        """(train, test) by sweep. ``test``: explicit sweep indices; else every k-th sweep with
        k = round(1 / test_fraction), starting from the last, so both halves span the commands
        when they were designed in order (``design_commands`` shuffles per fan)."""
        n = len(self)
        if n < 2:
            raise DataSourceError(f'a held-out split needs at least 2 sweeps; the data set has {n}: '
                                  f'record more sweeps at different commands')
        if test is None:
            if not 0 < test_fraction < 1:
                raise DataSourceError(f'test_fraction must be in (0, 1); got {test_fraction}')
            step = max(2, int(round(1 / test_fraction)))
            test = list(range(n - 1, -1, -step))
        test = sorted({int(i) for i in test})
        if not test or len(test) >= n or min(test) < 0 or max(test) >= n:
            raise DataSourceError(f'held-out sweeps {test} must be a non-empty proper subset of 0..{n - 1}')
        train = [i for i in range(n) if i not in test]
        return self[train], self[test]

    def folds(self, k: int) -> list[tuple['SweepSet', 'SweepSet']]:
        """k (train, test) splits by sweep, each sweep held out once."""
        n = len(self)
        if not 2 <= k <= n:
            raise DataSourceError(f'{k} folds need between 2 and {n} sweeps')
        return [self.split(test=list(range(i, n, k))) for i in range(k)]

    def fit_data(self, cell: float | None = 0.03) -> FitData:
        """Every sweep reduced to cell means on a ``cell`` [m] grid (None: raw finite samples)."""
        if cell is not None and not cell > 0:
            raise DataSourceError(f'cell must be > 0 m or None; got {cell}')
        parts = [_bin_sweep(s, cell, i) for i, s in enumerate(self.sweeps)]
        return FitData.concatenate(parts) if parts else FitData(
            np.zeros((0, len(self.fan_names))), np.zeros((0, 2)), np.zeros(0), np.zeros(0, int),
            np.zeros(0, int))

    def measurements(self) -> Measurements:
        """Every raw sample pooled (``core.tunnel.Measurements``)."""
        return Measurements.concatenate([s.to_measurements() for s in self.sweeps])

    def check_fans(self, fan_names: Sequence[str]) -> None:
        """Raise if the data's fan order is not ``fan_names`` (a model for another tunnel)."""
        if tuple(fan_names) != tuple(self.fan_names):
            raise DataSourceError(f'the sweeps are for fans {list(self.fan_names)}, the model for '
                                  f'{list(fan_names)}: use the config of the tunnel they were recorded on')


# -- sources ------------------------------------------------------------------------------------

def from_sim(tunnel, commands: np.ndarray, *, n_samples: int = 1000, source: str | None = None) -> SweepSet:
    """Sweep ``tunnel`` (anything satisfying ``core.tunnel.Tunnel``) once at each row of
    ``commands`` (n_sweeps, n_fans) [fraction]; ``n_samples`` plate samples per sweep."""
    commands = np.atleast_2d(np.asarray(commands, dtype=float))
    fans = tunnel.geometry.fans
    if commands.shape[1] != fans.n_fans:
        raise DataSourceError(f'commands have {commands.shape[1]} columns for {fans.n_fans} fans')
    sweeps = []
    for U in commands:
        tunnel.apply(U)
        sweeps.append(tunnel.sweep(n_samples))
    tunnel.apply(np.zeros(fans.n_fans))
    return SweepSet(tuple(sweeps), fans.names, source or repr(tunnel),
                    tuple(f'sim#{i}' for i in range(len(sweeps))))


def from_bag(bag_path, fan_names: Sequence[str] | None = None, **options) -> SweepSet:
    """The sweeps of a rosbag2 recording (``wind_shaper.bag.read_sweep_records``; ``options``
    go to it, e.g. ``segment_by='commands'``). Fan order: the bag's FanCommand names, or
    ``fan_names`` when given (the bag's must then match)."""
    try:
        from ..bag.sweeps import read_sweep_records
    except ImportError as exc:  # the bag subpackage is built by the node-graph work
        raise DataSourceError(f'reading bags needs wind_shaper.bag ({exc}); install the ROS '
                              f'message support with `bash tools/dev.sh setup`') from None
    records = read_sweep_records(bag_path, **options)
    if not records:
        raise DataSourceError(f'no sweeps found in the bag {bag_path}: it needs the force and '
                              f'plate-pose topics while the fans were commanded')
    names = tuple(fan_names) if fan_names is not None else tuple(records[0].fan_names)
    for r in records:
        if r.fan_names and tuple(r.fan_names) != names:
            raise DataSourceError(f'bag {bag_path} commands fans {list(r.fan_names)}, expected '
                                  f'{list(names)}: pass the tunnel config it was recorded with')
    labels = tuple(f'bag row {r.iteration + 1}' if r.source == 'experiment' else
                   f'bag k={r.iteration}' if r.iteration >= 0 else f'bag #{i}'
                   for i, r in enumerate(records))
    return SweepSet(tuple(r.sweep for r in records), names, f'bag {bag_path}', labels)


def from_run_folder(folder) -> SweepSet:
    """The sweeps of every completed iteration of a coordinator run folder
    (``<root>/<name>/iterations/kNNN/sweep.npz``, read through ``storage.runstore.RunStore``)."""
    folder = Path(folder)
    if not (folder / 'run.yaml').is_file():
        raise DataSourceError(f'{folder} is not a run folder (no run.yaml): give the folder the '
                              f'coordinator wrote for one run')
    try:
        from ..storage import RunStore
    except ImportError as exc:
        raise DataSourceError(f'reading run folders needs wind_shaper.storage.runstore ({exc})') from None
    store = RunStore.open(folder.parent, folder.name)
    history = store.load_history()
    if not history:
        raise DataSourceError(f'run folder {folder} has no completed iteration yet')
    return SweepSet(tuple(r.sweep for r in history), tuple(store.info.fan_names), f'run folder {folder}',
                    tuple(f'run k={r.k}' for r in history))


def from_experiment(folder) -> SweepSet:
    """The stored sweeps of an experiment folder (``wind-shaper collect``; read through
    ``storage.ExperimentStore``), in design order; rows flagged for a re-sweep or not swept yet
    are left out, with a warning that names them."""
    from ..storage import ExperimentStore
    folder = Path(folder)
    store = ExperimentStore.open(folder.parent, folder.name)
    stored = store.stored()
    if not stored:
        raise DataSourceError(f'experiment {folder} has no stored sweep yet: run `wind-shaper '
                              f'collect` with its design ({folder / "design.csv"})')
    missing = [store.plan.labels[i] for i in store.pending()]
    if missing:
        warnings.warn(f'experiment {folder}: {len(missing)} of {len(store.plan)} sweeps are not '
                      f'stored (flagged for a re-sweep or not swept yet: {", ".join(missing)}); '
                      f'using the {len(stored)} stored ones', stacklevel=2)
    return SweepSet(tuple(s.sweep for s in stored), tuple(store.plan.fan_names),
                    f'experiment {folder}', tuple(f'{s.label} (row {s.index + 1})' for s in stored))


def from_report(folder) -> SweepSet:
    """The sweeps a ``wind-shaper shape`` report folder kept (``run.json`` + ``sweeps.npz``)."""
    folder = Path(folder)
    try:
        doc = json.loads((folder / 'run.json').read_text())
        data = np.load(folder / 'sweeps.npz', allow_pickle=False)
    except (OSError, ValueError, EOFError, RecursionError) as exc:
        why = type(exc).__name__ if isinstance(exc, RecursionError) else str(exc)[:200]
        raise DataSourceError(f'{folder} is not a shape report folder ({why})') from None
    ks = sorted({key.split('_')[0] for key in data.files})
    sweeps = tuple(Sweep(data[f'{k}_positions'], data[f'{k}_forces'], data[f'{k}_times'], data[f'{k}_pwm'])
                   for k in ks)
    return SweepSet(sweeps, tuple(doc['fans']), f'shape report {folder}',
                    tuple(f'shape k={int(k[1:])}' for k in ks))


def load_sweeps(path, fan_names: Sequence[str] | None = None) -> SweepSet:
    """Sweeps from a bag (a folder with metadata.yaml, or an .mcap/.db3 file), a run folder
    (run.yaml), an experiment folder (experiment.yaml) or a shape report (run.json + sweeps.npz)."""
    path = Path(path)
    if not path.exists():
        raise DataSourceError(f'{path} does not exist: give a bag, a run folder or a shape report')
    if path.is_dir() and (path / 'run.yaml').is_file():
        data = from_run_folder(path)
    elif path.is_dir() and (path / 'experiment.yaml').is_file():
        data = from_experiment(path)
    elif path.is_dir() and (path / 'sweeps.npz').is_file():
        data = from_report(path)
    elif (path.is_dir() and (path / 'metadata.yaml').is_file()) or path.suffix in ('.mcap', '.db3'):
        data = from_bag(path, fan_names)
    else:
        raise DataSourceError(f'{path} is neither a bag (metadata.yaml), a run folder (run.yaml), '
                              f'an experiment (experiment.yaml) nor a shape report (sweeps.npz)')
    if fan_names is not None:
        data.check_fans(fan_names)
    return data
