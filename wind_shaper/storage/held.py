"""A held-plate calibration batch on disk, point by point, so that a guided batch resumes.

Layout of ``<root>/<name>/``::

    points.json     the batch: fan names and, per point, label, commands [fraction], x, y [m]
    record.jsonl    one line per recorded or skipped point, appended and fsynced: label, outcome
                    ('recorded' | 'skipped'), mean and std of the force [N], poses, mean plate
                    position [m], time [s, Unix]; a redo appends again (the last line of a label
                    wins)

Nothing here imports rclpy.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from ..core.errors import RunFolderError
from ..core.tunnel import Measurements
from .runstore import _atomic_write_text, folder_in

RECORDED, SKIPPED = 'recorded', 'skipped'


class HeldBatch:
    """A batch folder (see the module docstring). ``points``: dicts with label, pwm, x, y."""

    def __init__(self, folder: Path, fan_names: Sequence[str], points: list):
        self.folder, self.fan_names, self.points = folder, list(fan_names), points

    @classmethod
    def open(cls, root, name: str, fan_names: Sequence[str], points: list) -> 'HeldBatch':
        """Create the batch, or reopen it when it holds the same points (else RunFolderError:
        a batch is resumed, never silently changed)."""
        folder = folder_in(root, name, 'batch')
        doc = {'wind_shaper_held_batch': 1, 'fan_names': list(fan_names),
               'points': [{'label': p['label'], 'pwm': [float(u) for u in p['pwm']],
                           'x': float(p['x']), 'y': float(p['y'])} for p in points]}
        path = folder / 'points.json'
        if path.is_file():
            try:
                stored = json.loads(path.read_text())
            except (OSError, ValueError, RecursionError) as exc:
                why = type(exc).__name__ if isinstance(exc, RecursionError) else str(exc)[:200]
                raise RunFolderError(f'{path} is not readable ({why}): move {folder} away') from None
            if stored != doc:
                raise RunFolderError(f'the batch {folder} holds other points (another plan or '
                                     f'tunnel): choose another --batch name to start a new one')
        else:
            if folder.exists() and any(folder.iterdir()):
                raise RunFolderError(f'{folder} exists and is not a held-plate batch: choose '
                                     f'another --batch name')
            folder.mkdir(parents=True, exist_ok=True)
            _atomic_write_text(path, json.dumps(doc, indent=1))
        return cls(folder, fan_names, doc['points'])

    def outcomes(self) -> dict:
        """{label: the last line recorded for it}."""
        out = {}
        path = self.folder / 'record.jsonl'
        if path.is_file():
            for line in path.read_text().splitlines():
                try:
                    rec = json.loads(line)
                except (ValueError, RecursionError):   # a line cut by a crash: that point is simply not done
                    continue
                if not isinstance(rec, dict) or 'label' not in rec:
                    continue
                out[rec['label']] = rec
        return out

    def pending(self) -> list[int]:
        """Indices of the points with no line yet, in order."""
        done = self.outcomes()
        return [i for i, p in enumerate(self.points) if p['label'] not in done]

    def append(self, index: int, outcome: str, **values) -> dict:
        rec = {'label': self.points[index]['label'], 'outcome': outcome, 'time': time.time(),
               **{k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in values.items()}}
        path = self.folder / 'record.jsonl'
        cut = path.is_file() and path.stat().st_size > 0 and not path.read_bytes().endswith(b'\n')
        with open(path, 'a', encoding='utf-8') as fh:
            fh.write(('\n' if cut else '') + json.dumps(rec) + '\n')   # after a crash mid-line
            fh.flush()
            os.fsync(fh.fileno())
        return rec

    def measurements(self) -> Measurements:
        """The recorded points as held-plate measurements: commands, the mean plate position
        while recording [m], the mean force [N] (one row per point)."""
        done = self.outcomes()
        rows = [(p, done[p['label']]) for p in self.points
                if done.get(p['label'], {}).get('outcome') == RECORDED]
        if not rows:
            return Measurements(np.zeros((0, len(self.fan_names))), np.zeros((0, 2)), np.zeros(0))
        return Measurements(np.array([p['pwm'] for p, _ in rows]),
                            np.array([[r['x_mean'], r['y_mean']] for _, r in rows]),
                            np.array([r['force_mean'] for _, r in rows]))


__all__ = ['HeldBatch', 'RECORDED', 'SKIPPED']
