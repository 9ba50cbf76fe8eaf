"""storage.journal: every sample on disk as it arrives; a killed process loses none of them."""
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from wind_shaper.core.errors import ConfigError
from wind_shaper.storage.journal import (FORCE_FILE, OPEN_MARK, OUTCOME_FILE, POSE_FILE,
                                      SweepJournal, load_sweep_samples)


def test_samples_are_on_disk_as_soon_as_they_are_appended(tmp_path):
    journal = SweepJournal(tmp_path)
    folder = journal.begin()
    journal.append_force(1.0, 2.5)
    journal.append_pose(1.005, 0.1, -0.2)
    journal.append_force(1.001, 2.75)
    force, pose = load_sweep_samples(folder)     # read by another reader, before any close
    np.testing.assert_array_equal(force, [[1.0, 2.5], [1.001, 2.75]])
    np.testing.assert_array_equal(pose, [[1.005, 0.1, -0.2]])
    assert (folder / OPEN_MARK).exists()
    assert journal.close('estimated') == folder
    assert not (folder / OPEN_MARK).exists() and (folder / OUTCOME_FILE).read_text() == 'estimated\n'
    journal.append_force(9.0, 9.0)               # nothing open: not written anywhere
    assert len(load_sweep_samples(folder)[0]) == 2


KILLED_WRITER = r'''
import os, signal, sys
from wind_shaper.storage.journal import SweepJournal
journal = SweepJournal(sys.argv[1])
folder = journal.begin()
print(folder, flush=True)
for k in range(int(sys.argv[2])):
    journal.append_force(k * 1e-3, 0.5 * k)
    if k % 10 == 0:
        journal.append_pose(k * 1e-3, k, -k)
os.kill(os.getpid(), signal.SIGKILL)      # no close, no flush, no atexit
'''


def test_a_process_killed_with_sigkill_loses_no_sample_and_a_restart_takes_the_sweep_back(tmp_path):
    n = 2345
    done = subprocess.run([sys.executable, '-c', KILLED_WRITER, str(tmp_path), str(n)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == -signal.SIGKILL, done.stderr
    folder = tmp_path / os.path.basename(done.stdout.strip())
    force, pose = load_sweep_samples(folder)
    np.testing.assert_array_equal(force[:, 0], np.arange(n) * 1e-3)
    np.testing.assert_array_equal(force[:, 1], 0.5 * np.arange(n))
    assert len(pose) == len(range(0, n, 10))
    # the next process finds the open sweep, gets every sample back and appends after them
    journal = SweepJournal(tmp_path)
    back_force, back_pose = journal.reopen()
    np.testing.assert_array_equal(back_force, force)
    np.testing.assert_array_equal(back_pose, pose)
    assert journal.folder == folder
    journal.append_force(10.0, 1.0)
    journal.close('estimated')
    assert len(load_sweep_samples(folder)[0]) == n + 1


def test_a_torn_last_row_is_cut_before_appending(tmp_path):
    journal = SweepJournal(tmp_path)
    folder = journal.begin()
    journal.append_force(1.0, 2.0)
    journal.shutdown()                                   # stays open, like a crash
    with open(folder / FORCE_FILE, 'ab') as fh:
        fh.write(b'\x01\x02\x03')                        # a write cut short
    journal = SweepJournal(tmp_path)
    force, _ = journal.reopen()
    np.testing.assert_array_equal(force, [[1.0, 2.0]])
    journal.append_force(2.0, 3.0)
    np.testing.assert_array_equal(load_sweep_samples(folder)[0], [[1.0, 2.0], [2.0, 3.0]])


def test_a_new_sweep_abandons_the_open_one_and_old_sweeps_are_pruned(tmp_path):
    journal = SweepJournal(tmp_path, keep=3)
    first = journal.begin()
    journal.append_pose(0.0, 0.0, 0.0)
    second = journal.begin()
    assert (first / OUTCOME_FILE).read_text() == 'abandoned\n'
    assert len(load_sweep_samples(first)[1]) == 1        # kept, not thrown away
    assert journal.folder == second
    for _ in range(5):
        journal.begin()
        journal.close('estimated')
    closed = sorted(p.parent for p in tmp_path.glob(f'sweep-*/{OUTCOME_FILE}'))
    assert len(closed) == 3 and first not in closed
    assert SweepJournal(tmp_path).reopen() is None       # nothing open


def test_sweeps_begun_across_a_seconds_turn_sort_in_the_order_they_were_begun(tmp_path, monkeypatch):
    """The folder name's seconds and nanoseconds come from one clock reading: read apart, a
    sweep begun as the second turned sorted before the one begun just before it, and pruning
    removed the newer. A fake clock gives each reading in turn, 0.4 s apart across a turn."""
    import time as real_time
    from wind_shaper.storage import journal as journal_module
    readings = iter(int((1_795_000_000.5 + 0.4 * i) * 1e9) for i in range(100))

    class Clock:
        monotonic = staticmethod(real_time.monotonic)
        strftime = staticmethod(real_time.strftime)

        @staticmethod
        def time_ns():
            return next(readings)

        @staticmethod
        def gmtime(seconds=None):
            return real_time.gmtime(next(readings) / 1e9 if seconds is None else seconds)
    monkeypatch.setattr(journal_module, 'time', Clock)
    journal = SweepJournal(tmp_path, keep=3)
    begun = []
    for _ in range(6):
        begun.append(journal.begin())
        journal.close('estimated')
    assert sorted(begun) == begun
    kept = sorted(p.parent for p in tmp_path.glob(f'sweep-*/{OUTCOME_FILE}'))
    assert kept == begun[-3:]


def test_an_unwritable_journal_folder_is_refused_with_what_to_do(tmp_path):
    blocker = tmp_path / 'a_file'
    blocker.write_text('')
    with pytest.raises(ConfigError, match='journal_dir'):
        SweepJournal(blocker / 'journal')
    with pytest.raises(ConfigError, match='keep'):
        SweepJournal(tmp_path, keep=0)


def test_pose_file_name_is_part_of_the_format():
    assert (FORCE_FILE, POSE_FILE) == ('force.f64', 'pose.f64')
