"""coordination.experiment: a designed experiment driven by plain asyncio ports on the simulated
tunnel (no rclpy): rows stored, re-swept, flagged, resumed and cancelled; bad designs refused
before any fan is commanded."""
import asyncio

import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.coordination import (CANCELLED, CHECKING, COMMANDING, FAILED, SWEEPING,
                                      Experiment, FieldAnswer, IterationStopped, run_experiment)
from wind_shaper.core.errors import RunFolderError
from wind_shaper.experiment import DesignError, make_design
from wind_shaper.storage import FLAGGED, PENDING, STORED
from wind_shaper.workbench.data import load_sweeps
from sim_ports import SimPorts


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


def open_experiment(setup, root, spec='lhs:4', name='exp', **kw):
    b = setup.shaping.bounds
    d = make_design(spec, setup.geometry.fans, b.u_min, b.u_max, seed=kw.pop('seed', 0))
    return Experiment.open(setup, root, name, kw.pop('names', d.fan_names),
                           kw.pop('commands', d.commands), kw.pop('labels', d.labels), spec), d


def test_every_row_is_commanded_swept_checked_and_stored_in_design_order(setup, tmp_path):
    exp, design = open_experiment(setup, tmp_path)
    ports = SimPorts(setup)
    results = asyncio.run(run_experiment(exp, ports, max_sweeps=2))
    assert [r.outcome for r in results] == [STORED] * 4 and exp.states() == [STORED] * 4
    assert ports.states == [COMMANDING, SWEEPING, CHECKING] * 4
    assert np.allclose(np.array(ports.commanded), design.commands)
    assert [d[:2] for d in ports.done] == [(i, STORED) for i in range(4)]
    assert all(r.coverage == 1.0 for r in results)
    # the folder is a data set the workbench reads, with the design's commands
    data = load_sweeps(exp.folder, setup.geometry.fans.names)
    assert len(data) == 4 and np.allclose(data.commands, design.commands)
    assert (exp.folder / 'design.csv').is_file()


def test_a_refused_sweep_is_swept_again_at_the_same_commands_and_pooled(setup, tmp_path):
    exp, _ = open_experiment(setup, tmp_path, 'lhs:3')
    ports = SimPorts(setup, refuse=1)
    results = asyncio.run(run_experiment(exp, ports, max_sweeps=3))
    assert results[0].attempts == 2 and results[0].n_pairs == 2000
    assert ports.rows[:3] == [(0, 0), (0, 1), (0, 2)]
    assert len(ports.commanded) == 3 and 'sweeping again' in ports.warnings[0]


def test_a_row_that_keeps_missing_the_area_is_flagged_kept_and_swept_again_on_resume(setup, tmp_path):
    exp, _ = open_experiment(setup, tmp_path, 'lhs:3')
    ports = SimPorts(setup, refuse=2)
    results = asyncio.run(run_experiment(exp, ports, max_sweeps=2))
    assert [r.outcome for r in results] == [FLAGGED, STORED, STORED]
    assert 'a gap of 9 cm' in results[0].message and 'flagged' in ports.warnings[-1]
    take = exp.store.row_dir(0) / 'flagged-1.npz'
    assert take.is_file(), 'the flagged take is kept'
    assert 'flagged for a re-sweep' in exp.summary() and 'fans off' in exp.summary()
    with pytest.warns(UserWarning, match='not stored'):
        assert len(load_sweeps(exp.folder)) == 2  # a flagged row is never data
    # the same design again: only the flagged row is swept
    again, _ = open_experiment(setup, tmp_path, 'lhs:3')
    assert again.pending() == [0]
    ports = SimPorts(setup)
    asyncio.run(run_experiment(again, ports, max_sweeps=2))
    assert len(ports.commanded) == 1 and again.states() == [STORED] * 3
    assert take.is_file()


def test_a_cancel_keeps_the_rows_stored_before_it(setup, tmp_path):
    exp, _ = open_experiment(setup, tmp_path, 'lhs:4')
    ports = SimPorts(setup, cancel_after=4)   # 3 boundaries per row: cancelled after row 2's sweep
    with pytest.raises(IterationStopped) as stop:
        asyncio.run(run_experiment(exp, ports, max_sweeps=2))
    assert stop.value.state == CANCELLED
    assert exp.states() == [STORED, PENDING, PENDING, PENDING]
    again, _ = open_experiment(setup, tmp_path, 'lhs:4')
    assert again.pending() == [1, 2, 3]


def test_another_design_under_the_same_name_is_refused(setup, tmp_path):
    open_experiment(setup, tmp_path, 'lhs:4')
    with pytest.raises(RunFolderError, match='holds another design.*design.csv'):
        open_experiment(setup, tmp_path, 'lhs:4', seed=1)


@pytest.mark.parametrize('change, match', [
    (lambda c: c.__setitem__((1, 2), 0.97), 'outside the configured range'),
    (lambda c: c.__setitem__((1, 0), np.nan), 'not a number'),
])
def test_a_bad_table_is_refused_whole_before_anything_is_written(setup, tmp_path, change, match):
    b = setup.shaping.bounds
    d = make_design('lhs:4', setup.geometry.fans, b.u_min, b.u_max)
    commands = d.commands.copy()
    change(commands)
    with pytest.raises(DesignError, match=match):
        Experiment.open(setup, tmp_path, 'bad', d.fan_names, commands, d.labels, 'test')
    assert not (tmp_path / 'bad').exists()


def test_a_table_in_another_fan_order_is_reordered_and_wrong_fans_are_refused(setup, tmp_path):
    b = setup.shaping.bounds
    d = make_design('lhs:3', setup.geometry.fans, b.u_min, b.u_max)
    names = list(d.fan_names)[::-1]
    exp = Experiment.open(setup, tmp_path, 'rev', names, d.commands[:, ::-1], d.labels, 'reversed')
    assert np.allclose(exp.design.commands, d.commands)
    with pytest.raises(DesignError, match='not the tunnel'):
        Experiment.open(setup, tmp_path, 'bad', names[:-1] + ['XX'], d.commands, d.labels, 'x')
    with pytest.raises(DesignError, match='do not fill rows'):
        Experiment.open(setup, tmp_path, 'bad', names, d.commands.ravel()[:-1], [], 'x')


def test_a_sweep_without_any_pairs_stops_the_experiment_and_keeps_the_stored_rows(setup, tmp_path):
    exp, _ = open_experiment(setup, tmp_path, 'lhs:4')
    ports = SimPorts(setup)
    real = ports.estimate

    async def estimate(k, U):
        if len(ports.done) == 1:   # the force stream stopped after the first row
            return FieldAnswer(False, 'the force stream has no samples in the sweep')
        return await real(k, U)

    ports.estimate = estimate
    with pytest.raises(IterationStopped, match='no .force, pose. pairs.*force stream.*check the '
                                                'force sensor') as stop:
        asyncio.run(run_experiment(exp, ports, max_sweeps=3))
    assert stop.value.state == FAILED
    assert exp.states() == [STORED, PENDING, PENDING, PENDING]
    assert len(ports.commanded) == 2   # stopped at once, not after max_sweeps takes
