"""The sweep journal: every sample of the sweep being collected, on disk as it arrives.

A sweep costs minutes of a person's time; a crash of the process that collects it must not cost
the samples. ``SweepJournal`` keeps one folder per sweep under its root::

    <root>/sweep-<UTC time>-<ns>/
        force.f64   rows (t [s], Fz [N])        float64 little endian, appended per sample
        pose.f64    rows (t [s], x, y [m])      float64 little endian, appended per sample
        OPEN        present while the sweep is being collected
        outcome     'estimated' or 'abandoned' (why the sweep was closed), once closed

Each sample (or block of samples, as the force arrives) is one ``os.write`` on a file opened
for appending, so it is in the kernel's page cache as soon as it arrived: killing the process (SIGKILL included) loses none. The files are
fsynced at least every ``sync_period_s`` while samples arrive (and by ``sync()``, which the node
calls on a timer, and at ``close``), so a power cut loses at most that last batch. A process that starts again calls
``reopen()`` to get the unfinished sweep back and goes on appending to it. A torn last row (a
write cut short) is ignored on reading. The newest ``keep`` closed sweeps are kept.
"""
from __future__ import annotations

import os
import shutil
import struct
import threading
import time
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError

FORCE_FILE, POSE_FILE, OPEN_MARK, OUTCOME_FILE = 'force.f64', 'pose.f64', 'OPEN', 'outcome'
FORCE_COLUMNS, POSE_COLUMNS = 2, 3
_DTYPE = np.dtype('<f8')
_FORCE_ROW, _POSE_ROW = struct.Struct('<2d'), struct.Struct('<3d')


def read_rows(path: Path, columns: int) -> np.ndarray:
    """(rows, columns) float64 of a journal file; a torn last row is left out."""
    data = Path(path).read_bytes() if Path(path).is_file() else b''
    row_bytes = columns * _DTYPE.itemsize
    whole = len(data) - len(data) % row_bytes
    return np.frombuffer(data[:whole], dtype=_DTYPE).reshape(-1, columns).copy()


class SweepJournal:
    """On-disk twin of a sweep's sample buffers; see the module docstring.

    root: folder of the sweep folders (created if missing); keep: closed sweeps kept (>= 1);
    sync_period_s: fsync the open sweep's files at least this often while samples arrive [s]
    (0: after every sample). Appends come from stream callbacks, begin/close from services: a
    lock orders them."""

    def __init__(self, root, keep: int = 20, sync_period_s: float = 1.0):
        self.root = Path(root)
        if keep < 1:
            raise ConfigError(f'the journal must keep at least 1 closed sweep; got keep={keep}')
        if not (isinstance(sync_period_s, (int, float)) and 0 <= sync_period_s <= 3600):
            raise ConfigError(f'the journal\'s sync period must be 0..3600 s; got {sync_period_s!r}')
        self.keep = int(keep)
        self.sync_period_s = float(sync_period_s)
        self._last_sync = time.monotonic()
        self._dirty = False
        self.syncs = 0   # fsyncs of an open sweep's files (this process)
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            probe = self.root / '.write_test'
            probe.write_bytes(b'')
            probe.unlink()
        except OSError as exc:
            raise ConfigError(f'cannot write the sweep journal in {self.root}: {exc.strerror}; '
                              f'give a writable folder (journal_dir)') from None
        self._lock = threading.Lock()
        self._folder: Path | None = None
        self._fds: tuple[int, int] | None = None
        self.rows_written = [0, 0]   # force, pose rows of the open sweep (this process)

    # ------------------------------------------------------------------ state
    @property
    def folder(self) -> Path | None:
        """The open sweep's folder, or None."""
        return self._folder

    def _open_files(self, folder: Path) -> None:
        flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND
        self._fds = (os.open(folder / FORCE_FILE, flags, 0o644),
                     os.open(folder / POSE_FILE, flags, 0o644))
        self._folder = folder

    def _close_files(self, sync: bool) -> None:
        if self._fds is not None:
            for fd in self._fds:
                if sync:
                    os.fsync(fd)
                os.close(fd)
        self._fds, self._folder = None, None

    # ------------------------------------------------------------------ sweeps
    def begin(self) -> Path:
        """Start a new sweep (an open one is closed as 'abandoned'); returns its folder."""
        with self._lock:
            if self._folder is not None:
                self._close_locked('abandoned')
            # one clock reading for the seconds and the nanoseconds: read apart, a name made at
            # a second's turn took the old second's stamp and the new one's fraction and sorted
            # before the sweep made just before it (pruning then removed the newer one)
            now_ns = time.time_ns()
            stamp = time.strftime('%Y%m%d-%H%M%S', time.gmtime(now_ns // 1_000_000_000))
            folder = self.root / f'sweep-{stamp}-{now_ns % 1_000_000_000:09d}'
            folder.mkdir()
            (folder / OPEN_MARK).write_bytes(b'')
            self._open_files(folder)
            self.rows_written = [0, 0]
            self._prune_locked()
            return folder

    def append_force(self, t: float, fz: float) -> None:
        with self._lock:
            if self._fds is not None:
                os.write(self._fds[0], _FORCE_ROW.pack(t, fz))
                self.rows_written[0] += 1
                self._wrote_locked()

    def append_forces(self, t, fz) -> None:
        """A block of force samples (sequences of one length, oldest first), in one write: the
        same rows as ``append_force`` of each in turn."""
        data = b''.join(_FORCE_ROW.pack(ti, fi) for ti, fi in zip(t, fz))
        with self._lock:
            if self._fds is not None and data:
                os.write(self._fds[0], data)
                self.rows_written[0] += len(data) // _FORCE_ROW.size
                self._wrote_locked()

    def append_pose(self, t: float, x: float, y: float) -> None:
        with self._lock:
            if self._fds is not None:
                os.write(self._fds[1], _POSE_ROW.pack(t, x, y))
                self.rows_written[1] += 1
                self._wrote_locked()

    def sync(self) -> None:
        """fsync what was appended since the last sync (a timer calls it: samples that stop
        arriving would otherwise wait for the next one)."""
        with self._lock:
            self._sync_locked()

    def _wrote_locked(self) -> None:
        self._dirty = True
        if time.monotonic() - self._last_sync >= self.sync_period_s:
            self._sync_locked()

    def _sync_locked(self) -> None:
        if self._fds is not None and self._dirty:
            for fd in self._fds:
                os.fsync(fd)
            self.syncs += 1
        self._dirty = False
        self._last_sync = time.monotonic()

    def close(self, outcome: str) -> Path | None:
        """Close the open sweep with ``outcome`` ('estimated' | 'abandoned'); returns its folder."""
        with self._lock:
            return self._close_locked(outcome)

    def _close_locked(self, outcome: str) -> Path | None:
        folder = self._folder
        if folder is None:
            return None
        self._close_files(sync=True)
        (folder / OUTCOME_FILE).write_text(outcome + '\n')
        (folder / OPEN_MARK).unlink(missing_ok=True)
        self._prune_locked()
        return folder

    def reopen(self) -> tuple[np.ndarray, np.ndarray] | None:
        """After a restart: the unfinished sweep's (force rows, pose rows), reopened for appending
        (a torn last row is cut off first); None when no sweep was open. Older unfinished sweeps
        (there should be none) are closed as 'abandoned'."""
        with self._lock:
            unfinished = sorted(p.parent for p in self.root.glob(f'sweep-*/{OPEN_MARK}'))
            if not unfinished:
                return None
            for folder in unfinished[:-1]:
                (folder / OUTCOME_FILE).write_text('abandoned\n')
                (folder / OPEN_MARK).unlink(missing_ok=True)
            folder = unfinished[-1]
            rows = []
            for name, columns in ((FORCE_FILE, FORCE_COLUMNS), (POSE_FILE, POSE_COLUMNS)):
                data = read_rows(folder / name, columns)
                path = folder / name
                if path.is_file() and path.stat().st_size != data.nbytes:
                    os.truncate(path, data.nbytes)   # drop a torn row before appending
                rows.append(data)
            self._open_files(folder)
            self.rows_written = [0, 0]
            return rows[0], rows[1]

    def _prune_locked(self) -> None:
        closed = sorted(p.parent for p in self.root.glob(f'sweep-*/{OUTCOME_FILE}'))
        for folder in closed[:-self.keep]:
            shutil.rmtree(folder, ignore_errors=True)

    def shutdown(self) -> None:
        """Close the files, leaving an open sweep open (a restart reopens it)."""
        with self._lock:
            self._close_files(sync=True)


def load_sweep_samples(folder) -> tuple[np.ndarray, np.ndarray]:
    """(force rows (t, Fz), pose rows (t, x, y)) of one journal sweep folder."""
    folder = Path(folder)
    return read_rows(folder / FORCE_FILE, FORCE_COLUMNS), read_rows(folder / POSE_FILE, POSE_COLUMNS)


__all__ = ['SweepJournal', 'load_sweep_samples', 'read_rows']
