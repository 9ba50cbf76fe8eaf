"""coordination.iteration: the coordinator's run and state machine, driven by plain asyncio ports
on the simulated tunnel (no rclpy)."""
import asyncio
from dataclasses import replace
import math

import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.coordination import (CANCELLED, COMMANDING, ESTIMATING, FAILED, SWEEPING,
                                      UPDATING, FanWatch, IterationStopped,
                                      ShapingRun, run_iteration, start_at_prior_optimum)
from wind_shaper.core.errors import WindShaperError
from sim_ports import SimPorts


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


def open_run(setup, tmp_path, target='parabolic', name='r'):
    return ShapingRun.open(setup, tmp_path, name, target, {'test': True})


def test_an_iteration_goes_through_its_states_writes_the_run_and_advances(setup, tmp_path):
    run = open_run(setup, tmp_path)
    assert run.k == 0 and run.command is None and math.isnan(run.last_rmse)
    # a new run starts at the prior's optimum for its target, not at a fixed command
    warm = start_at_prior_optimum(setup, setup.load_model(), 'parabolic')
    assert run.warm is not None and np.allclose(run.U, warm.U)
    assert not np.allclose(warm.U[setup.geometry.fans.enabled], 0.5, atol=0.01)
    ports = SimPorts(setup)
    _, rule = run.prepare()
    data = asyncio.run(run_iteration(run, ports, rule, max_sweeps=3))
    assert ports.states == [COMMANDING, SWEEPING, ESTIMATING, UPDATING]
    assert np.allclose(ports.commanded[0], warm.U)
    # the first sweep is checked against the prediction, and the tunnel time is counted
    check = data.info['warm_start']['check']
    assert check['mismatch'] is False and check['rms_difference_N'] > 0
    assert data.info['plate_s'] >= 0 and data.info['settle_s'] >= 0 and data.info['sweeps'] == 1
    assert run.k == 1 and np.allclose(run.U, data.pwm_after) and np.allclose(run.command, run.U)
    assert run.last_rmse == pytest.approx(data.rmse)
    lo, hi = setup.shaping.u_min, setup.shaping.u_max
    assert np.all((data.pwm_after >= lo - 1e-12) & (data.pwm_after <= hi + 1e-12))
    assert data.rmse_predicted_after < data.rmse  # the step is predicted to help
    # resuming the folder gives the same run state and the history the rule learns from
    again = open_run(setup, tmp_path)
    assert again.k == 1 and np.allclose(again.U, run.U) and len(again.history) == 1
    assert again.last_rmse == pytest.approx(data.rmse)


def test_on_weaker_fans_the_coordinator_steps_from_its_first_sweep_instead_of_starting_again(
        setup, tmp_path, monkeypatch):
    # every fan at 75 % thrust, uniform profile: the first sweep's error calls for a restart,
    # the first update sees the step that closes it, so the run takes that step (as ShapingLoop)
    from wind_shaper.control.warm_start import WarmStart
    from wind_shaper.sim import make_effect
    on = setup.geometry.fans.enabled

    def first_iteration(name):
        run = open_run(setup, tmp_path, target='uniform', name=name)
        ports = SimPorts(setup)
        ports.sim = setup.make_sim(seed=0, effects=[make_effect('weak_fan', fan=f, gain=0.75)
                                                    for f in setup.geometry.fans.names])
        _, rule = run.prepare()
        return asyncio.run(run_iteration(run, ports, rule, max_sweeps=3))
    data = first_iteration('declined')
    check = data.info['warm_start']['check']
    assert check['restart_declined'] and not check['restart'], check
    assert 'restart_next' not in data.info and 'steps from here' in data.info['warm_start']['check_text']
    assert not np.allclose(data.pwm_after[on], 0.5)
    # were the step to keep more of the error than the share allows, the run would start again
    keep = WarmStart.after_first_step
    monkeypatch.setattr(WarmStart, 'after_first_step',
                        staticmethod(lambda check, predicted, share=0.0: keep(check, predicted, 0.0)))
    data = first_iteration('restarted')
    assert data.info['warm_start']['check']['restart'] and 'restart_next' in data.info
    assert np.allclose(data.pwm_after[on], 0.5)

def test_a_refused_sweep_is_swept_again_and_pooled(setup, tmp_path):
    run = open_run(setup, tmp_path)
    ports = SimPorts(setup, refuse=1)
    data = asyncio.run(run_iteration(run, ports, run.prepare()[1], max_sweeps=3))
    assert ports.states.count(SWEEPING) == 2 and len(ports.warnings) == 1
    assert 'a gap of 9 cm' in ports.warnings[0] and '2 of 3' in ports.warnings[0]
    assert len(data.sweep) == 2000 and run.k == 1 and data.info['sweeps'] == 2


def test_too_many_refusals_fail_and_nothing_advances(setup, tmp_path):
    run = open_run(setup, tmp_path)
    ports = SimPorts(setup, refuse=5)
    with pytest.raises(IterationStopped) as stop:
        asyncio.run(run_iteration(run, ports, run.prepare()[1], max_sweeps=2))
    assert stop.value.state == FAILED and 'after 2 sweep(s)' in str(stop.value)
    assert run.k == 0 and np.allclose(run.U, start_at_prior_optimum(setup, setup.load_model(), 'parabolic').U)
    assert open_run(setup, tmp_path).k == 0  # nothing written


def test_a_cancel_at_a_boundary_leaves_the_run_where_it_was(setup, tmp_path):
    run = open_run(setup, tmp_path)
    ports = SimPorts(setup, cancel_after=1)
    with pytest.raises(IterationStopped) as stop:
        asyncio.run(run_iteration(run, ports, run.prepare()[1], max_sweeps=3))
    assert stop.value.state == CANCELLED
    assert UPDATING not in ports.states and run.k == 0


def test_a_bad_request_is_refused_before_anything_changes(setup, tmp_path):
    run = open_run(setup, tmp_path)
    with pytest.raises(WindShaperError):
        run.prepare('expr:__import__("os")')
    with pytest.raises(WindShaperError, match='uniform'):
        run.prepare('uniform:500')  # far beyond what the fans deliver
    assert run.target_spec == 'parabolic'
    target, _ = run.prepare('uniform:2.5')
    assert run.set_target('uniform:2.5', target) and run.target_spec == 'uniform:2.5'
    assert open_run(setup, tmp_path).target_spec == 'uniform:2.5'  # kept in the run folder


def test_a_resumed_run_keeps_its_own_target_and_says_so(setup, tmp_path):
    open_run(setup, tmp_path, target='parabolic')
    run = open_run(setup, tmp_path, target='uniform')
    assert run.target_spec == 'parabolic'
    assert any(level == 'warning' and 'new runs only' in text for level, text in run.notes)


def test_set_model_refuses_a_broken_model_and_keeps_the_old(setup, tmp_path):
    run = open_run(setup, tmp_path)
    old = run.model
    with pytest.raises(WindShaperError):
        run.set_model('model: {kind: no_such_term}\n', 'broken.yaml')
    assert run.model is old and not run.store.model_path.exists()
    text = setup.model_path.read_text()
    assert repr(run.set_model(text, 'model.yaml')) == repr(old)
    assert run.store.model_path.read_text() == text


def test_the_fan_watch_names_the_fan_that_left_its_command():
    watch = FanWatch(0.0, [0.5, 0.5, 0.5], tolerance=0.01)
    watch.saw(0.5, np.array([0.5, 0.5, 0.5]))
    assert watch.problem(1.0, 2.0, ['A', 'B', 'C']) == ''
    watch.saw(1.5, np.array([0.5, 0.2, 0.5]))
    assert 'B at 0.200 instead of 0.500' in watch.problem(2.0, 2.0, ['A', 'B', 'C'])
    quiet = FanWatch(0.0, [0.5], tolerance=0.01)
    assert 'did not report' in quiet.problem(3.0, 2.0, ['A'])


def test_with_region_sweeps_on_the_graph_sweeps_only_the_changed_region_and_fuses(setup, tmp_path):
    """shaping.sweep.region.enabled: the first iteration sweeps everything; the next ones pass
    their region to the sweep and the estimator, fuse the answer with what they carry over,
    and record it; a resumed run plans its region from the stored history."""
    sweep = {**dict(setup.shaping.sweep or {}), 'region': {'enabled': True}}
    on = replace(setup, shaping=replace(setup.shaping, sweep=sweep))
    run = open_run(on, tmp_path, target='gaussian@LM1')
    ports = SimPorts(on, seed=4)
    records = [asyncio.run(run_iteration(run, ports, run.prepare()[1], max_sweeps=2)) for _ in range(4)]
    assert ports.plans[0] is None and 'region' not in records[0].info
    planned = [i for i, p in enumerate(ports.plans) if p is not None]
    assert planned and planned[0] >= 1
    for i in planned:
        plan, info = ports.plans[i], records[i].info['region']
        assert info['needed'] == [int(j) for j in np.flatnonzero(plan.needed)]
        assert 0 < info['share'] < 1 and np.isfinite(info['consistency'])
        # the stored estimate is the fused one: carried key points keep about their carried std
        std = records[i].estimate.std
        assert np.all(std[~plan.needed] <= plan.carried_std[~plan.needed] + 1e-9)
        assert 'sweeping' in ShapingRun.done_message(records[i]) and 'carried over' in ShapingRun.done_message(records[i])
    again = open_run(on, tmp_path, target='gaussian@LM1')
    plan = again.region_plan(again.U, again.prepare()[1])
    assert plan is None or plan.share < 1
    assert again.history[-1].info.get('region', {}).get('needed') == records[-1].info.get('region', {}).get('needed')


def test_the_done_message_says_when_a_step_stayed_before_a_fitted_dip():
    from types import SimpleNamespace
    data = SimpleNamespace(k=1, rmse=0.9, rmse_predicted_after=0.85, step_size=1.0, sweep=[0] * 10,
                           info={'ridge': {'t': 0.45, 'height': 1.22, 'start': 0.86, 'end': 0.68}})
    text = ShapingRun.done_message(data)
    assert 'stays on this side of a ridge' in text and '21% better' in text and '1.4 x worse' in text
    data.info = {'ridge': None}
    assert 'ridge' not in ShapingRun.done_message(data)
