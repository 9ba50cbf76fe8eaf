"""storage.experiments: the experiment folder keeps every stored row and flagged take, resumes
only the same design, and survives a crash between a row's files."""
import numpy as np
import pytest

from wind_shaper.core.errors import RunFolderError
from wind_shaper.core.tunnel import Sweep
from wind_shaper.experiment import make_design
from wind_shaper.app import Setup
from wind_shaper.storage import FLAGGED, PENDING, STORED, ExperimentPlan, ExperimentStore


def plan(seed=0, n=4):
    fans = Setup.load().geometry.fans
    d = make_design(f'lhs:{n}', fans, 0.0, 0.6, seed=seed)
    return ExperimentPlan(d.source, d.fan_names, d.commands, d.labels, np.zeros((5, 2)))


def sweep(U, n=50, seed=0):
    rng = np.random.default_rng(seed)
    return Sweep(rng.uniform(0, 0.2, (n, 2)), rng.normal(1, 0.1, n), np.arange(n) * 0.01, U)


def test_rows_go_from_pending_to_flagged_to_stored_and_read_back(tmp_path):
    p = plan()
    store = ExperimentStore.open(tmp_path, 'e', p)
    assert store.states() == [PENDING] * 4 and np.all(np.isnan(store.coverage()))
    store.write_flagged(1, sweep(p.commands[1]), {'coverage': 0.8, 'message': 'a gap'})
    store.write_flagged(1, None, {'coverage': 0.0, 'message': 'no samples'})
    store.write_sweep(0, sweep(p.commands[0]), {'coverage': 1.0})
    assert store.states() == [STORED, FLAGGED, PENDING, PENDING]
    assert store.pending() == [1, 2, 3]
    assert store.coverage()[:2].tolist() == [1.0, 0.0]
    assert sorted(x.name for x in store.row_dir(1).iterdir()) == [
        'flagged-1.json', 'flagged-1.npz', 'flagged-2.json']
    again = ExperimentStore.open(tmp_path, 'e')   # without a plan: as stored
    [row] = again.stored()
    assert row.index == 0 and row.label == p.labels[0] and row.record['coverage'] == 1.0
    assert np.allclose(row.sweep.forces, sweep(p.commands[0]).forces)
    assert np.allclose(again.plan.commands, p.commands)


def test_a_sweep_at_other_commands_than_its_row_is_refused(tmp_path):
    p = plan()
    store = ExperimentStore.open(tmp_path, 'e', p)
    with pytest.raises(RunFolderError, match='the design says'):
        store.write_sweep(1, sweep(p.commands[2]), {})
    with pytest.raises(RunFolderError, match='not a row'):
        store.write_sweep(7, sweep(p.commands[2]), {})


def test_a_crash_before_the_record_leaves_the_row_pending(tmp_path):
    p = plan()
    store = ExperimentStore.open(tmp_path, 'e', p)
    store.write_sweep(2, sweep(p.commands[2]), {})
    (store.row_dir(2) / 'record.json').unlink()    # as if killed between the two files
    assert store.row_state(2) == PENDING


def test_only_the_same_design_resumes_and_other_folders_are_left_alone(tmp_path):
    ExperimentStore.open(tmp_path, 'e', plan())
    ExperimentStore.open(tmp_path, 'e', plan())
    with pytest.raises(RunFolderError, match='another design'):
        ExperimentStore.open(tmp_path, 'e', plan(seed=3))
    (tmp_path / 'run').mkdir()
    (tmp_path / 'run' / 'run.yaml').write_text('x')
    with pytest.raises(RunFolderError, match='shaping run folder'):
        ExperimentStore.open(tmp_path, 'run', plan())
    (tmp_path / 'junk').mkdir()
    (tmp_path / 'junk' / 'a.txt').write_text('x')
    with pytest.raises(RunFolderError, match='not an experiment folder'):
        ExperimentStore.open(tmp_path, 'junk', plan())
    with pytest.raises(RunFolderError, match='plain folder name'):
        ExperimentStore.open(tmp_path, '../x', plan())


@pytest.mark.parametrize('damage', ['truncated', 'empty', 'garbage', 'pickled'])
def test_a_damaged_sweep_file_is_a_run_folder_error_naming_the_row(tmp_path, damage):
    """A sweep.npz cut short (a copy interrupted, a full disk) raised EOFError out of the
    reader; any damage now ends in RunFolderError saying which row and what to do."""
    p = plan()
    store = ExperimentStore.open(tmp_path, 'e', p)
    store.write_sweep(0, sweep(p.commands[0]), {'coverage': 1.0})
    path = store.row_dir(0) / 'sweep.npz'
    data = path.read_bytes()
    if damage == 'truncated':
        path.write_bytes(data[:len(data) // 2])
    elif damage == 'empty':
        path.write_bytes(b'')
    elif damage == 'garbage':
        path.write_bytes(b'PK\x03\x04' + bytes(range(256)) * 4)
    else:   # an object array: np.load would unpickle it
        np.savez(path.with_name('x.npz'), t=np.array([object()], dtype=object), x=[0.0], y=[0.0],
                 force=[0.0], pwm=p.commands[0])
        path.with_name('x.npz').replace(path)
    with pytest.raises(RunFolderError) as refused:
        ExperimentStore.open(tmp_path, 'e').stored()
    assert 'row 0' in str(refused.value) and 'move' in str(refused.value)


def test_a_truncated_sweep_through_load_sweeps_is_a_clear_refusal(tmp_path):
    from wind_shaper.core.errors import WindShaperError
    from wind_shaper.workbench.data import load_sweeps
    p = plan()
    store = ExperimentStore.open(tmp_path, 'e', p)
    store.write_sweep(0, sweep(p.commands[0]), {'coverage': 1.0})
    path = store.row_dir(0) / 'sweep.npz'
    path.write_bytes(path.read_bytes()[:300])
    with pytest.raises(WindShaperError, match='cut short or damaged'):
        load_sweeps(tmp_path / 'e')


def test_states_are_read_from_the_folder_once_and_kept_up_to_date_by_the_writes(tmp_path,
                                                                               monkeypatch):
    """The collect service's status asks for every row's state twice a second: with 1000 rows
    reading them from disk took about 50 ms on the executor each time. The store reads them
    when it is opened, then its own writes keep them; nothing reads the folder per status."""
    p = plan(n=6)
    store = ExperimentStore.open(tmp_path, 'e', p)
    store.write_sweep(0, sweep(p.commands[0]), {'coverage': 1.0})
    reads = []
    real = ExperimentStore.row_state
    monkeypatch.setattr(ExperimentStore, 'row_state',
                        lambda self, i: reads.append(i) or real(self, i))
    for _ in range(3):
        assert store.states() == [STORED] + [PENDING] * 5
    assert reads == []
    store.write_flagged(2, sweep(p.commands[2]), {'coverage': 0.5})
    store.write_sweep(3, sweep(p.commands[3]), {'coverage': 1.0})
    store.write_flagged(3, None, {'coverage': 0.0})   # a flagged take never un-stores a row
    assert store.states() == [STORED, PENDING, FLAGGED, STORED, PENDING, PENDING]
    assert store.pending() == [1, 2, 4, 5] and reads == []
    # what the folder holds agrees, read afresh
    assert ExperimentStore.open(tmp_path, 'e').states() == store.states()
    assert store.refresh() == store.states() and len(reads) == 12


@pytest.mark.parametrize('reader', ['stored', 'coverage'])
def test_a_record_nested_too_deep_is_a_run_folder_error(tmp_path, reader):
    """json raised RecursionError out of the reader on a record.json of 100,000 nested lists."""
    p = plan()
    store = ExperimentStore.open(tmp_path, 'e', p)
    store.write_sweep(0, sweep(p.commands[0]), {'coverage': 1.0})
    (store.row_dir(0) / 'record.json').write_text('[' * 100_000 + ']' * 100_000)
    with pytest.raises(RunFolderError) as refused:
        getattr(ExperimentStore.open(tmp_path, 'e'), reader)()
    assert 'row 0' in str(refused.value) and 'move' in str(refused.value)
    assert len(str(refused.value)) < 400
