"""Experiment designs: the fan commands of a set of sweeps, checked before any fan sees them.

A design is a table: one row per sweep, one column per fan, commands as fractions 0..1 of full
PWM in the tunnel's fan order. ``make_design(spec, fans, u_min, u_max)`` builds one from

* ``lhs:N``: N sweeps, the first and last with every fan off (a background or dead band shows
  there), the rest a Latin hypercube over [u_min, u_max] (each fan spread evenly, independently
  of the others: what the diagnosis needs to tell the fans' effects apart);
* ``lhs:N+level``: the same and two more sweeps, before the last, each with every enabled fan at
  one command: the middle of the range, then ``LOW_LEVEL`` of the way up it, where a run's
  optimum keeps many fans (the level sweeps the shaping's update keeps among a run's maps,
  ``AdaptiveUpdate.level_map``; the recommended commissioning is ``lhs:6+level``);
* ``single-off``: every fan at the middle of the range, then each enabled fan off in turn;
* a CSV file (header: ``label`` (optional) then the fan names, in any order; one row per sweep) or
  a YAML file (``design: [{label: ..., pwm: {FAN: value, ...}}, ...]``).

Every design is validated the same way: the fans must be exactly the tunnel's, every command a
finite number within [u_min, u_max] or exactly 0 (off), disabled fans at 0. A bad design is refused whole with
``DesignError`` naming the sweep, the fan and the value, and what to do; nothing is half-used.
``write_design`` saves a design as CSV (what ``make_design`` reads back).
"""
from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ..core.errors import WindShaperError
from ..core.geometry import FanArray
from ..core.limits import excerpt
from ..core.safe_yaml import read_text_file, read_yaml_file

#: Where the low level sweep of ``lhs:N+level`` runs every fan, as a share of the way from u_min
#: to u_max: below the middle, where a run's optimum keeps many fans (edge fans under a peaked
#: profile, fans that starve their neighbours) and where a fan's curve has its dead band or stall.
#: Screened at 0.2, 0.3 and 0.4 of the way (0.2 and 0.3 alike, 0.4 worse) and at 0.77 and 1.0
#: (worse; see the benchmarks).
LOW_LEVEL = 0.3

__all__ = ['Design', 'DesignError', 'design_commands', 'check_design', 'make_design',
           'write_design']


class DesignError(WindShaperError, ValueError):
    """A design that cannot be run: the message says what is wrong and what to do."""


def design_commands(n_fans: int, n_sweeps: int, *, low: float = 0.0, high: float = 0.9,
                    seed: int = 0, enabled: np.ndarray | None = None) -> np.ndarray:
    """(n_sweeps, n_fans) commands [fraction] for a diagnostic data set: a Latin hypercube, so
    every fan's commands spread evenly over [low, high] (dead band and saturation included) and
    are uncorrelated with the other fans' (each fan's effect can be told apart). Disabled fans 0."""
    if n_sweeps < 1 or not 0 <= low < high <= 1:
        raise DesignError(f'design needs n_sweeps >= 1 and 0 <= low < high <= 1; got '
                          f'{n_sweeps}, {low}, {high}')
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xD0E]))
    levels = low + (high - low) * (np.arange(n_sweeps) + rng.uniform(0.2, 0.8, (n_fans, n_sweeps))) / n_sweeps
    U = np.array([rng.permutation(row) for row in levels]).T
    if enabled is not None:
        U = U * np.asarray(enabled, dtype=bool)[None, :]
    return U


@dataclass(frozen=True)
class Design:
    """commands (S, n_fans) [fraction 0..1, fan order of ``fan_names``]; labels (S,); source: the
    spec it came from."""

    fan_names: tuple
    commands: np.ndarray
    labels: tuple
    source: str

    def __len__(self) -> int:
        return len(self.commands)

    def spread(self, enabled) -> float:
        """The median over the enabled fans of the interquartile range of each fan's command
        (what ``SweepSet.command_spread`` measures on recorded sweeps) [fraction]."""
        U = self.commands[:, np.asarray(enabled, bool)]
        if len(U) < 2 or U.shape[1] == 0:
            return 0.0
        q75, q25 = np.percentile(U, [75, 25], axis=0)
        return float(np.median(q75 - q25))


def check_design(names, commands, labels, fans: FanArray, u_min: float, u_max: float,
                 source: str) -> Design:
    """The design of the table ``commands`` (S, len(names)) [fraction] with columns ``names`` (any
    order) and one label per row, reordered to the tunnel's fan order; DesignError naming the
    sweep, fan and value when it cannot run (see the module docstring)."""
    commands = np.asarray(commands, dtype=float)
    if commands.ndim != 2 or len(commands) == 0:
        raise DesignError(f'{source}: the design has no sweeps; give at least one row of commands')
    if commands.shape[1] != len(names):
        raise DesignError(f'{source}: {commands.shape[1]} commands per sweep for {len(names)} fans; '
                          f'give one command per fan')
    if len(labels) != len(commands):
        raise DesignError(f'{source}: {len(labels)} labels for {len(commands)} sweeps; give one '
                          f'per sweep')
    want = list(fans.names)
    missing, unknown = sorted(set(want) - set(names)), sorted(set(names) - set(want))
    if missing or unknown or len(names) != len(set(names)):
        raise DesignError(f'{source}: the design\'s fans {list(names)} are not the tunnel\'s {want}'
                          + (f' (missing: {missing})' if missing else '')
                          + (f' (unknown: {unknown})' if unknown else '')
                          + '; write one column per fan of tunnel.yaml')
    order = [list(names).index(n) for n in want]
    commands = commands[:, order]
    for i, row in enumerate(commands):
        for j, u in enumerate(row):
            where = f'{source}: sweep {labels[i]!r}, fan {want[j]}'
            if not np.isfinite(u):
                raise DesignError(f'{where}: the command {u!r} is not a number; write a fraction 0..1')
            if not fans.enabled[j] and u != 0:
                raise DesignError(f'{where}: the fan is disabled in tunnel.yaml but commanded {u:g}; '
                                  f'write 0 or enable it')
            if fans.enabled[j] and u != 0 and not (u_min - 1e-12 <= u <= u_max + 1e-12):
                raise DesignError(f'{where}: the command {u:g} lies outside the configured range '
                                  f'[{u_min:g}, {u_max:g}] (shaping.yaml u_min/u_max); the fans '
                                  f'never receive it: change the design or the range')
    return Design(tuple(want), commands, tuple(labels), source)


def _read_csv(path: Path):
    try:
        text = read_text_file(path)
        rows = [r for r in csv.reader(io.StringIO(text, newline=''))
                if r and any(c.strip() for c in r)]
    except OSError as exc:
        raise DesignError(f'cannot read the design {path}: {exc.strerror or exc}') from None
    except (WindShaperError, csv.Error) as exc:
        raise DesignError(f'cannot read the design {path}: {exc}') from None
    if not rows:
        raise DesignError(f'{path}: empty; write a header (label, then the fan names) and one row per sweep')
    header = [c.strip() for c in rows[0]]
    has_label = header[0].lower() == 'label'
    names = header[1:] if has_label else header
    labels, commands = [], []
    for k, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise DesignError(f'{path}, line {k}: {len(row)} values for {len(header)} columns')
        cells = row[1:] if has_label else row
        try:
            commands.append([float(c) for c in cells])
        except ValueError:
            raise DesignError(f'{path}, line {k}: {excerpt(", ".join(cells))} holds something that '
                              f'is not a number; write fractions 0..1') from None
        labels.append(row[0].strip() if has_label else f'sweep {k - 1}')
    return names, np.array(commands, dtype=float).reshape(len(commands), len(names)), labels


def _read_yaml(path: Path):
    try:
        doc = read_yaml_file(path)
    except (OSError, yaml.YAMLError) as exc:
        raise DesignError(f'cannot read the design {path}: {exc}') from None
    sweeps = doc.get('design') if isinstance(doc, dict) else None
    if not isinstance(sweeps, list) or not all(isinstance(s, dict) and isinstance(s.get('pwm'), dict)
                                               for s in sweeps):
        raise DesignError(f'{path}: write `design:` as a list of sweeps, each '
                          f'{{label: ..., pwm: {{FAN: fraction, ...}}}}')
    names = list(sweeps[0]['pwm']) if sweeps else []
    for i, s in enumerate(sweeps):
        if set(s['pwm']) != set(names):
            raise DesignError(f'{path}: sweep {i + 1} names fans {sorted(s["pwm"])}, the first names '
                              f'{sorted(names)}; every sweep must name the same fans')
    try:
        commands = np.array([[float(s['pwm'][n]) for n in names] for s in sweeps], dtype=float)
    except (TypeError, ValueError):
        raise DesignError(f'{path}: every pwm value must be a number (a fraction 0..1)') from None
    labels = [str(s.get('label', f'sweep {i + 1}')) for i, s in enumerate(sweeps)]
    return names, commands.reshape(len(sweeps), len(names)), labels


def make_design(spec: str, fans: FanArray, u_min: float, u_max: float, *, seed: int = 0) -> Design:
    """The design of ``spec`` (see the module docstring) for ``fans``, within [u_min, u_max]."""
    spec = str(spec).strip()
    n = fans.n_fans
    mid = 0.5 * (u_min + u_max)
    if spec.startswith('lhs:'):
        body, level = (spec[4:-len('+level')], True) if spec.endswith('+level') else (spec[4:], False)
        try:
            count = int(body)
        except ValueError:
            count = 0
        if count < 3:
            raise DesignError(f'{spec!r}: write lhs:N with N >= 3 sweeps (the first and last are '
                              f'fans off; lhs:N+level adds two with every fan at one command); the '
                              f'diagnosis wants 8-12')
        inner = design_commands(n, count - 2, low=u_min, high=u_max, seed=seed, enabled=fans.enabled)
        commands = np.vstack([np.zeros(n), inner, np.zeros(n)])
        labels = ['fans off'] + [f'lhs {i + 1}' for i in range(count - 2)] + ['fans off again']
        if level:   # every fan at one command, twice, before the last sweep with fans off
            low = u_min + LOW_LEVEL * (u_max - u_min)
            rows = [np.where(fans.enabled, u, 0.0) for u in (mid, low)]
            commands = np.vstack([commands[:-1], *rows, commands[-1:]])
            labels = labels[:-1] + ['level (middle)', 'level (low)'] + labels[-1:]
        return check_design(list(fans.names), commands, labels, fans, u_min, u_max, spec)
    if spec == 'single-off':
        rows, labels = [np.where(fans.enabled, mid, 0.0)], ['all at the middle']
        for j in np.flatnonzero(fans.enabled):
            row = rows[0].copy()
            row[j] = 0.0
            rows.append(row)
            labels.append(f'{fans.names[j]} off')
        return check_design(list(fans.names), np.array(rows), labels, fans, u_min, u_max, spec)
    path = Path(spec)
    if path.suffix.lower() == '.csv':
        names, commands, labels = _read_csv(path)
    elif path.suffix.lower() in ('.yaml', '.yml'):
        names, commands, labels = _read_yaml(path)
    else:
        raise DesignError(f'unknown design {spec!r}: give lhs:N, lhs:N+level, single-off, or a .csv or .yaml file')
    return check_design(names, commands, labels, fans, u_min, u_max, str(path))


def write_design(path, design: Design) -> Path:
    """Save ``design`` as CSV: label, then one column per fan [fraction]; exact floats."""
    path = Path(path)
    with open(path, 'w', newline='', encoding='utf-8') as stream:
        writer = csv.writer(stream)
        writer.writerow(['label', *design.fan_names])
        for label, row in zip(design.labels, design.commands):
            writer.writerow([label, *(repr(float(u)) for u in row)])
    return path
