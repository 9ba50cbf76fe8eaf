"""Biasing the force sensor (bias_zero), opt-in, in a designed experiment and in a shaping
iteration: never by default, on the fans-off rows once they settled, or before every sweep with
the fans off; the plan is pure logic (core.bias), and run_experiment and run_iteration ask the
port in the right order."""
import asyncio

import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.coordination import (BIAS_MODES, Experiment, FieldAnswer, ShapingRun, bias_plan,
                                      run_experiment, run_iteration)
from wind_shaper.coordination.experiment import BIAS_AT_ROW, BIAS_BEFORE_ROW, NO_BIAS
from wind_shaper.core.bias import check_bias_mode
from wind_shaper.core.errors import ConfigError
from wind_shaper.experiment import make_design
from sim_ports import SimPorts

TABLE = np.array([[0.0, 0.0], [0.3, 0.5], [0.0, 0.0], [0.6, 0.0]])


def test_the_plan_biases_only_with_every_fan_off_and_never_by_default():
    assert bias_plan(TABLE, 'never') == [NO_BIAS] * 4
    assert bias_plan(TABLE, 'fans_off') == [BIAS_AT_ROW, NO_BIAS, BIAS_AT_ROW, NO_BIAS]
    assert bias_plan(TABLE, 'every_sweep') == [BIAS_AT_ROW, BIAS_BEFORE_ROW, BIAS_AT_ROW,
                                               BIAS_BEFORE_ROW]
    assert set(BIAS_MODES) == {'never', 'fans_off', 'every_sweep'}


def test_an_unknown_mode_is_refused_with_the_modes_it_knows():
    with pytest.raises(ConfigError, match='never, fans_off, every_sweep'):
        bias_plan(TABLE, 'always')


class BiasPorts(SimPorts):
    """SimPorts that log the fans' commands and the bias requests in order."""

    def __init__(self, setup, run=None):
        super().__init__(setup)
        self.log = []
        self.run = run

    async def command_fans(self, U):
        self.log.append(('fans', tuple(np.round(U, 3))))
        if self.run is not None:
            # the coordinator publishes the run's command in force, so it must be the one waited for
            assert np.allclose(self.run.command, U), (self.run.command, U)
        await super().command_fans(U)

    async def estimate(self, k, U, plan=None):  # the estimate is not what this test is about
        n = len(self.key_points)
        return FieldAnswer(True, '', self.key_points, np.zeros(n), np.ones(n), self.pooled(U), 1000, 0.01)

    async def bias_sensor(self):
        assert np.all(self.sim.pwm == 0), 'the sensor is biased only with every fan off'
        self.log.append(('bias',))


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


def _run(setup, tmp_path, mode):
    b = setup.shaping.bounds
    d = make_design('lhs:4', setup.geometry.fans, b.u_min, b.u_max, seed=0)  # fans off first and last
    exp = Experiment.open(setup, tmp_path, mode, d.fan_names, d.commands, d.labels, 'lhs:4')
    ports = BiasPorts(setup)
    asyncio.run(run_experiment(exp, ports, max_sweeps=1, bias_zero=mode))
    return ports.log


def test_run_experiment_biases_after_the_fans_off_rows_settle_or_before_every_row(setup, tmp_path):
    log = _run(setup, tmp_path, 'fans_off')
    assert [e[0] for e in log] == ['fans', 'bias', 'fans', 'fans', 'fans', 'bias']
    log = _run(setup, tmp_path, 'every_sweep')
    kinds = [e[0] for e in log]
    assert kinds.count('bias') == 4
    # a fans-on row: fans off, bias, then the row's commands
    i = kinds.index('bias', 2)
    assert log[i - 1][0] == 'fans' and not any(log[i - 1][1]) and any(log[i + 1][1])


def _iterate(setup, tmp_path, mode, iterations=2):
    run = ShapingRun.open(setup, tmp_path, 'biased', 'parabolic', {'test': True})
    ports = BiasPorts(setup, run)
    for _ in range(iterations):
        _, rule = run.prepare()
        data = asyncio.run(run_iteration(run, ports, rule, max_sweeps=1, bias_zero=mode))
    return ports.log, data


def test_a_shaping_iteration_biases_with_every_fan_off_before_its_commands_only_when_asked(setup, tmp_path):
    log, _ = _iterate(setup, tmp_path / 'never', 'never')
    assert [e[0] for e in log] == ['fans', 'fans']
    log, data = _iterate(setup, tmp_path / 'every', 'every_sweep')
    assert [e[0] for e in log] == ['fans', 'bias', 'fans'] * 2
    assert not any(log[0][1]) and any(log[2][1])
    # the bias is stamped, and the spin-down before it counts in the iteration's settle time
    stamps = data.timestamps
    assert stamps['started'] <= stamps['biased'] <= stamps['applied']
    assert data.info['settle_s'] == pytest.approx(stamps['sweep_started'] - stamps['started'], abs=1e-3)


def test_a_shaping_iteration_refuses_an_unknown_bias_mode_before_touching_the_fans(setup, tmp_path):
    run = ShapingRun.open(setup, tmp_path, 'bad', 'parabolic', {'test': True})
    ports = BiasPorts(setup)
    with pytest.raises(ConfigError, match='every_sweep'):
        asyncio.run(run_iteration(run, ports, run.prepare()[1], max_sweeps=1, bias_zero='hourly'))
    assert ports.log == [] and run.k == 0


def test_biasing_before_every_sweep_is_refused_where_the_fans_may_not_stop():
    """every_sweep turns every fan off before each sweep; with a lowest command above 0 the
    fans would never report 0, so it is refused at once, with the setting to change."""
    assert check_bias_mode('every_sweep', 0.0) == 'every_sweep'
    assert check_bias_mode('fans_off', 0.1) == 'fans_off' and check_bias_mode('never', 0.1) == 'never'
    with pytest.raises(ConfigError, match=r'u_min = 0\.1 .*set u_min to 0 .* or bias_zero to never'):
        check_bias_mode('every_sweep', 0.1)
