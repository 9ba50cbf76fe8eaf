"""The sweep journal under SIGKILL at many moments, and its periodic fsync.

A writer process appends numbered samples (force row i = (i, 2 i), pose row j = (j, j, -j)) to
the journal and reports how many it has written; it is killed with SIGKILL at random moments,
and each new writer takes the unfinished sweep back (``reopen``) and goes on from what is there.
After every kill the files must read (a torn row is left out, never refused), hold exactly the
rows 0..n-1 in order, and n must be at least what the writer had reported: nothing written
before the kill is lost."""
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from wind_shaper.core.errors import ConfigError
from wind_shaper.storage.journal import OPEN_MARK, SweepJournal, load_sweep_samples

WRITER = textwrap.dedent('''
    import sys, time
    from wind_shaper.storage.journal import SweepJournal
    j = SweepJournal(sys.argv[1], sync_period_s=float(sys.argv[2]))
    back = j.reopen()
    if back is None:
        j.begin()
        n_f = n_p = 0
    else:
        n_f, n_p = len(back[0]), len(back[1])
    print(f'start {n_f} {n_p}', flush=True)
    while True:
        for _ in range(10):
            j.append_force(float(n_f), 2.0 * n_f)
            n_f += 1
        j.append_pose(float(n_p), float(n_p), -float(n_p))
        n_p += 1
        print(f'wrote {n_f} {n_p}', flush=True)
        time.sleep(0.001)
''')


def _run_and_kill(root, sync_s, after_s):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, '-c', WRITER, str(root), str(sync_s)],
                            stdout=subprocess.PIPE, text=True, env=env)
    start = proc.stdout.readline().split()
    assert start[0] == 'start', start
    time.sleep(after_s)
    os.kill(proc.pid, signal.SIGKILL)
    out, _ = proc.communicate(timeout=10)
    lines = [ln.split() for ln in out.splitlines() if ln.startswith('wrote')]
    reported = (int(lines[-1][1]), int(lines[-1][2])) if lines else (int(start[1]), int(start[2]))
    return (int(start[1]), int(start[2])), reported


def test_sigkill_at_many_moments_loses_nothing_and_the_next_writer_resumes(tmp_path):
    rng = np.random.default_rng(7)
    root = tmp_path / 'journal'
    previous = (0, 0)
    for kill in range(12):
        start, reported = _run_and_kill(root, 0.05, float(rng.uniform(0.0, 0.25)))
        (folder,) = [p.parent for p in root.glob(f'sweep-*/{OPEN_MARK}')]   # still one open sweep
        force, pose = load_sweep_samples(folder)
        # the new writer resumed exactly where the last left off
        assert start[0] >= previous[0] and start[1] >= previous[1], (kill, start, previous)
        assert len(force) >= reported[0] and len(pose) >= reported[1], (kill, len(force), reported)
        np.testing.assert_array_equal(force, np.column_stack([np.arange(len(force)), 2.0 * np.arange(len(force))]))
        np.testing.assert_array_equal(pose, np.column_stack([np.arange(len(pose)), np.arange(len(pose)),
                                                             -np.arange(len(pose))]))
        previous = (len(force), len(pose))
    assert previous[0] > 500   # the writers got real work done between the kills


def test_appends_are_fsynced_at_least_every_period(tmp_path, monkeypatch):
    synced = []
    real = os.fsync
    monkeypatch.setattr(os, 'fsync', lambda fd: (synced.append(fd), real(fd)))
    every = SweepJournal(tmp_path / 'a', sync_period_s=0.0)
    every.begin()
    for i in range(5):
        every.append_force(float(i), 0.0)
    assert every.syncs == 5 and len(synced) == 10      # both files, after every sample
    lazy = SweepJournal(tmp_path / 'b', sync_period_s=3600.0)
    lazy.begin()
    for i in range(5):
        lazy.append_force(float(i), 0.0)
    assert lazy.syncs == 0
    lazy.sync()                                        # the node's timer
    assert lazy.syncs == 1
    lazy.sync()                                        # nothing new: no fsync
    assert lazy.syncs == 1
    with pytest.raises(ConfigError, match='sync period'):
        SweepJournal(tmp_path / 'c', sync_period_s=-1.0)
