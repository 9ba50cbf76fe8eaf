"""The coordinator's run folder: creation, reopening, iterations, and crashes mid-write."""
import json

import numpy as np
import pytest

from wind_shaper.storage import runstore as rs
from wind_shaper.estimation.field import FieldEstimator
from wind_shaper.core.geometry import TunnelGeometry
from wind_shaper.storage.runstore import IterationData, RunFolderError, RunInfo, RunStore
from wind_shaper.report.run_report import write_report
from wind_shaper.sim import SimulatedTunnel

FANS = ('LM1', 'HM1', 'LM2', 'HM2', 'LM3', 'HM3', 'CM')


@pytest.fixture(scope='module')
def geometry():
    return TunnelGeometry.paper_rig()


@pytest.fixture
def info(geometry):
    return RunInfo('parabolic', tuple(geometry.fans.names), geometry.key_points,
                   {'shaping': {'u0': 0.5}})


@pytest.fixture(scope='module')
def sim(geometry):
    return SimulatedTunnel(geometry, seed=3)


def iteration(sim, k, pwm_before, pwm_after, target='parabolic'):
    """Data of iteration k measured on the simulated tunnel (600-sample sweep)."""
    sim.apply(pwm_before)
    sweep = sim.sweep(600)
    est = FieldEstimator(min_samples=10, max_gap=0.2).estimate(sweep, sim.geometry.key_points)
    target_values = np.full(len(est.mean), 2.5)
    rmse = float(np.sqrt(np.mean((est.mean - target_values) ** 2)))
    return IterationData(k, target, np.asarray(pwm_before, float), np.asarray(pwm_after, float),
                         0.8 / (k + 1), rmse, 0.9 * rmse, est, target_values, sweep,
                         model='FanJets(...)', timestamps={'started': 1.0 + k, 'finished': 2.0 + k},
                         info={'gain': 0.8, 'quiet': np.bool_(k > 0), 'radius': np.float64(0.1),
                               'weights': np.arange(3.0)})


def test_new_run_starts_before_iteration_zero(tmp_path, info):
    store = RunStore.open(tmp_path, 'run1', info, initial_pwm=np.full(7, 0.5))
    assert store.folder == tmp_path / 'run1'
    assert store.last_completed() == -1
    st = store.state()
    assert st.next_k == 0 and st.target == 'parabolic'
    np.testing.assert_array_equal(st.next_pwm, np.full(7, 0.5))
    assert store.load_history() == []
    reopened = RunStore.open(tmp_path, 'run1')  # without info: reads run.yaml
    assert reopened.info.fan_names == FANS
    np.testing.assert_allclose(reopened.info.key_points, info.key_points, atol=1e-9)
    assert reopened.info.config == {'shaping': {'u0': 0.5}} and reopened.info.created_at


def test_iterations_are_recorded_and_history_rebuilds_records(tmp_path, info, sim):
    store = RunStore.open(tmp_path, 'r', info, initial_pwm=np.full(7, 0.5))
    U = [np.full(7, 0.5), np.full(7, 0.45), np.full(7, 0.42)]
    written = [iteration(sim, k, U[k], U[k + 1]) for k in range(2)]
    for d in written:
        store.write_iteration(d)
    reopened = RunStore.open(tmp_path, 'r', info)
    assert reopened.last_completed() == 1
    np.testing.assert_array_equal(reopened.state().next_pwm, U[2])
    history = reopened.load_history()
    assert [r.k for r in history] == [0, 1]
    for rec, d in zip(history, written):
        np.testing.assert_array_equal(rec.pwm, d.pwm_before)
        np.testing.assert_array_equal(rec.next_pwm, d.pwm_after)
        np.testing.assert_array_equal(rec.estimate.mean, d.estimate.mean)
        np.testing.assert_array_equal(rec.estimate.std, d.estimate.std)
        np.testing.assert_array_equal(rec.sweep.forces, d.sweep.forces)
        np.testing.assert_array_equal(rec.sweep.positions, d.sweep.positions)
        np.testing.assert_array_equal(rec.sweep.times, d.sweep.times)
        assert rec.error == pytest.approx(d.rmse ** 2, rel=1e-12)
        assert rec.step_size == d.step_size
        assert rec.info['rmse_predicted_after_N'] == pytest.approx(0.9 * d.rmse)
        # the update rule's info survives as plain JSON (numpy values as numbers and lists)
        assert rec.info['quiet'] is (d.k > 0) and rec.info['weights'] == [0.0, 1.0, 2.0]
        assert rec.info['radius'] == 0.1 and rec.info['gain'] == 0.8
    doc = store.load_record(1)
    assert doc['timestamps'] == {'started': 2.0, 'finished': 3.0} and doc['model'] == 'FanJets(...)'
    assert doc['fan_names'] == list(FANS) and doc['n_samples'] == 600


def test_history_feeds_the_report(tmp_path, info, sim, geometry):
    store = RunStore.open(tmp_path, 'r', info, initial_pwm=np.full(7, 0.5))
    store.write_iteration(iteration(sim, 0, np.full(7, 0.5), np.full(7, 0.45)))
    out = write_report(tmp_path / 'report', store.load_history(), geometry, {'run': 'r'})
    doc = json.loads((out / 'run.json').read_text())
    assert [it['k'] for it in doc['iterations']] == [0]
    assert doc['iterations'][0]['n_sweep_samples'] == 600


def test_a_crash_mid_iteration_keeps_the_previous_state(tmp_path, info, sim, monkeypatch):
    store = RunStore.open(tmp_path, 'r', info, initial_pwm=np.full(7, 0.5))
    store.write_iteration(iteration(sim, 0, np.full(7, 0.5), np.full(7, 0.45)))
    before = store.state_path.read_bytes()
    real = rs._atomic_write_text
    calls = []

    def crash_on_field(path, text):
        calls.append(path.name)
        if path.name == 'field.json':
            raise OSError('disk full (simulated)')
        real(path, text)

    monkeypatch.setattr(rs, '_atomic_write_text', crash_on_field)
    with pytest.raises(OSError, match='simulated'):
        store.write_iteration(iteration(sim, 1, np.full(7, 0.45), np.full(7, 0.40)))
    assert calls == ['record.json', 'field.json']
    monkeypatch.setattr(rs, '_atomic_write_text', real)
    # a restart sees iteration 0 as the last one, with its commands; the partial k001 is ignored
    reopened = RunStore.open(tmp_path, 'r', info)
    assert store.state_path.read_bytes() == before
    assert reopened.last_completed() == 0
    np.testing.assert_array_equal(reopened.state().next_pwm, np.full(7, 0.45))
    assert [r.k for r in reopened.load_history()] == [0]
    assert not reopened.iteration_dir(1).exists()
    # and iteration 1 can be run again
    reopened.write_iteration(iteration(sim, 1, np.full(7, 0.45), np.full(7, 0.40)))
    assert reopened.last_completed() == 1
    assert not list((tmp_path / 'r' / 'iterations').glob('.*'))


@pytest.mark.fault
def test_a_crash_while_writing_the_state_keeps_the_old_one(tmp_path, info, sim, monkeypatch, fault_row):
    store = RunStore.open(tmp_path, 'r', info, initial_pwm=np.full(7, 0.5))
    before = store.state_path.read_bytes()
    real_replace = rs.os.replace

    def crash_on_state(src, dst):
        if str(dst).endswith('state.json'):
            raise OSError('power cut (simulated)')
        real_replace(src, dst)

    monkeypatch.setattr(rs.os, 'replace', crash_on_state)
    with pytest.raises(OSError, match='simulated'):
        store.write_iteration(iteration(sim, 0, np.full(7, 0.5), np.full(7, 0.45)))
    monkeypatch.undo()
    assert store.state_path.read_bytes() == before  # the old state, whole
    reopened = RunStore.open(tmp_path, 'r', info)
    assert reopened.last_completed() == -1 and reopened.load_history() == []
    # the folder renamed into place before the crash is replaced by the rerun
    assert reopened.iteration_dir(0).exists()
    reopened.write_iteration(iteration(sim, 0, np.full(7, 0.5), np.full(7, 0.44)))
    assert reopened.last_completed() == 0
    np.testing.assert_array_equal(reopened.load_history()[0].next_pwm, np.full(7, 0.44))
    fault_row('a crash while the run state is written',
              'atomic rename: the old state stays readable', True)


def test_iterations_must_follow_in_order(tmp_path, info, sim):
    store = RunStore.open(tmp_path, 'r', info, initial_pwm=np.full(7, 0.5))
    with pytest.raises(RunFolderError, match='k=1 does not follow'):
        store.write_iteration(iteration(sim, 1, np.full(7, 0.5), np.full(7, 0.45)))
    with pytest.raises(RunFolderError, match='7 finite PWM'):
        store.write_iteration(iteration(sim, 0, np.full(7, 0.5), np.full(6, 0.45)))
    assert store.last_completed() == -1


def test_target_changes_persist(tmp_path, info):
    store = RunStore.open(tmp_path, 'r', info, initial_pwm=np.full(7, 0.5))
    store.set_target('uniform:2.0')
    st = RunStore.open(tmp_path, 'r', info).state()
    assert st.target == 'uniform:2.0' and st.last_completed == -1


def test_a_run_cannot_continue_on_another_tunnel(tmp_path, info, geometry):
    RunStore.open(tmp_path, 'r', info, initial_pwm=np.full(7, 0.5))
    other = RunInfo('parabolic', tuple(geometry.fans.names[:6]) + ('XX',), geometry.key_points)
    with pytest.raises(RunFolderError, match='XX'):
        RunStore.open(tmp_path, 'r', other)
    fewer = RunInfo('parabolic', tuple(geometry.fans.names), geometry.key_points[:10])
    with pytest.raises(RunFolderError, match='key points'):
        RunStore.open(tmp_path, 'r', fewer)


def test_bad_names_and_foreign_folders_are_refused(tmp_path, info):
    with pytest.raises(RunFolderError, match='plain folder name'):
        RunStore.open(tmp_path, '../escape', info, initial_pwm=np.full(7, 0.5))
    with pytest.raises(RunFolderError, match='no run at'):
        RunStore.open(tmp_path, 'missing')
    (tmp_path / 'foreign').mkdir()
    (tmp_path / 'foreign' / 'notes.txt').write_text('x')
    with pytest.raises(RunFolderError, match='not a run folder'):
        RunStore.open(tmp_path, 'foreign', info, initial_pwm=np.full(7, 0.5))
    (tmp_path / 'broken').mkdir()
    (tmp_path / 'broken' / 'run.yaml').write_text('just text')
    with pytest.raises(RunFolderError, match='not a readable run description'):
        RunStore.open(tmp_path, 'broken', info)


@pytest.mark.parametrize('name', ['record.json', 'field.json'])
def test_an_iteration_file_nested_too_deep_is_a_run_folder_error(tmp_path, info, sim, name):
    """json raised RecursionError out of load_history on a file of 100,000 nested lists."""
    store = RunStore.open(tmp_path, 'r', info, initial_pwm=np.full(7, 0.5))
    store.write_iteration(iteration(sim, 0, np.full(7, 0.5), np.full(7, 0.45)))
    (store.iteration_dir(0) / name).write_text('[' * 100_000 + ']' * 100_000)
    with pytest.raises(RunFolderError) as refused:
        RunStore.open(tmp_path, 'r', info).load_history()
    assert 'RecursionError' in str(refused.value) and len(str(refused.value)) < 400
