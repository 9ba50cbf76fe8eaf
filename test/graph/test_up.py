"""`wind-shaper up --sim` as a real command: six node processes on the simulated rig, brought up,
used and stopped, with every child checked by PID."""
import json
import os
import re
import shutil
import signal
import time
from pathlib import Path

import pytest
from graph_lock import graph_alone
from up_driver import NODES, UP_LINE, alive, children_of, node_pids

pytestmark = [pytest.mark.ros, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(120)
def test_up_brings_every_node_up_and_sigint_leaves_nothing_running(up):
    u = up('--startup-timeout', '60')
    m = u.wait_line(UP_LINE.pattern, 75)
    pids = node_pids(m)
    assert set(pids) == set(NODES) and int(m.group(1)) == len(NODES)
    print(f'all nodes visible after {m.group(2)} s')
    assert sorted(children_of(u.process.pid)) == sorted(pids.values())
    assert all(alive(pid) for pid in pids.values())
    u.wait_line(r'wind-shaper iterate --target parabolic', 5)
    time.sleep(1.0)   # let the rig run a moment: streams flowing when stopped
    u.process.send_signal(signal.SIGINT)
    assert u.wait(30) == 0, u.output()[-4000:]
    stopped = u.wait_line(r'wind-shaper up: stopped \((.*)\)', 1)
    assert 'STILL RUNNING' not in stopped.group(0)
    assert all(f'{n}: 0' in stopped.group(1) for n in NODES), stopped.group(0)
    assert not [pid for pid in pids.values() if alive(pid)], 'a node outlived wind-shaper up'


@pytest.mark.timeout(150)
def test_up_restarts_a_node_that_dies(up):
    u = up()
    pids = node_pids(u.wait_line(UP_LINE.pattern, 75))
    os.kill(pids['mocap_relay'], signal.SIGKILL)
    u.wait_line(r'node mocap_relay \(pid \d+\) exited with code -9', 10)
    u.wait_line(r'restarting mocap_relay \(1 of 3\)', 10)
    u.process.send_signal(signal.SIGTERM)
    assert u.wait(30) == 0
    assert not [pid for pid in children_of(u.process.pid) if alive(pid)]
    assert not alive(pids['sim_tunnel'])


@pytest.mark.timeout(300)
def test_up_runs_iterations_through_the_graph_and_writes_the_report(up, tmp_path):
    with graph_alone():   # the errors of the iterations are compared
        u = up('--iterations', '3', '--target', 'parabolic', '--run-name', 'graph-test',
               '--set', 'coordinator.sweep_duration_s=5.0', '--set', 'coordinator.settle_s=0.5',
               # a host stalled by other work loses poses and leaves holes; more sweeps fill them
               '--set', 'coordinator.max_sweeps=5')
        assert u.wait(280) == 0, u.output()[-6000:]
    out = u.output()
    rmse = [float(x) for x in re.findall(r'k=\s*\d+\s+RMSE ([\d.]+) N', out)]
    assert len(rmse) == 3, out[-4000:]
    run = tmp_path / 'runs' / 'graph-test'
    assert (run / 'run.yaml').is_file() and (run / 'iterations' / 'k002' / 'record.json').is_file()
    report = json.loads((run / 'report' / 'run.json').read_text())
    errors = [it['rmse_N'] for it in report['iterations']]
    assert errors == pytest.approx(rmse, abs=1e-3)
    # the run starts at the prior's optimum (the warm start), which the first sweep confirmed;
    # the measured updates then take the error below it
    first = json.loads((run / 'iterations' / 'k000' / 'record.json').read_text())
    assert first['info']['warm_start']['check']['mismatch'] is False, first['info']['warm_start']
    assert 'warm start at the prior' in out
    # from the warm start the updates can only gain a little, within the estimate's noise
    # (0.751 -> 0.706 -> 0.716 N in one CI run): it must fall, and not come back above the start
    assert min(errors[1:]) < errors[0] and errors[-1] < 1.02 * errors[0], \
        f'the error did not fall: {errors}'
    used = report['tunnel_time_s']   # plate and fan-settle time per iteration and in total
    assert len(used['plate_s']) == 3, used
    for k, plate_s in enumerate(used['plate_s']):
        # each 5 s sweep, with the estimate that refused it when one more was needed (a loaded
        # host loses poses: 5 sweeps and 33.6 s in one CI run): within 10 s a sweep
        sweeps = json.loads((run / 'iterations' / f'k{k:03d}' / 'record.json').read_text())['info']['sweeps']
        assert 1 <= sweeps <= 5 and 4.0 < plate_s < 10.0 * sweeps, (k, plate_s, sweeps, used)
    assert used['total_s'] == pytest.approx(used['plate_total_s'] + used['settle_total_s'])
    for png in ('field_maps.png', 'error.png', 'pwm.png'):
        assert (run / 'report' / png).stat().st_size > 1000
    print(f'RMSE per iteration through the graph: {errors}; plate time {used["plate_s"]} s')


@pytest.mark.timeout(240)
def test_a_sweep_ends_once_the_estimate_is_good_enough(up, tmp_path):
    # the simulated plate would sweep for 40 s; the coordinator watches the estimate (coverage
    # and largest std, live in its status) and ends the sweep through the stop service. The
    # shipped threshold (an RMS of 2.0 x the noise floor, 0.10 N) is met on the parabola about
    # when the plate's tour has covered the disc once: this test's config asks for 3.0 x, so what
    # is tested is the ending, not how small the std gets. On a loaded host the peeks come late
    # (good enough after 21.2 s in one CI run, where a 20 s sweep was asked): the sweep is long
    # enough that ending it is still told apart from its running out
    config = tmp_path / 'config'
    shutil.copytree(ROOT / 'config', config)
    shaping = config / 'shaping.yaml'
    text = shaping.read_text()
    assert 'std_factor: 2.0 ' in text
    shaping.write_text(text.replace('std_factor: 2.0 ', 'std_factor: 3.0 '))
    # and the force sensor biased first, every fan off (bias_zero every_sweep: a drifting zero)
    # two iterations: the second starts with the fans at the first's next commands, so its
    # bias needs them told off (not merely found off, as they are when the graph starts)
    u = up('--iterations', '2', '--target', 'parabolic', '--run-name', 'short-sweep',
           '--set', 'coordinator.sweep_duration_s=40.0', '--set', 'coordinator.sweep_min_s=3.0',
           '--set', 'coordinator.settle_s=0.5', '--set', 'coordinator.max_sweeps=3',
           '--set', 'coordinator.bias_zero=every_sweep', '--config', str(config))
    assert u.wait(220) == 0, u.output()[-6000:]
    out = u.output()
    m = re.search(r'the estimate is good enough after ([\d.]+) s \(coverage 100 %, std '
                  r'([\d.]+) N RMS <= ([\d.]+) N, largest ([\d.]+) N\): ending the sweep', out)
    assert m, out[-5000:]
    assert float(m.group(2)) <= float(m.group(3)) and float(m.group(4)) <= 2.0 * float(m.group(3))
    assert 3.0 <= float(m.group(1)) < 36.0, m.group(0)
    # plate time counts every sweep: a loaded machine can lose samples, the estimator refuses
    # the first sweep and the plate sweeps again (in full when it was refused, 40 s): the sweep
    # that was good enough must still have ended early
    record = json.loads((tmp_path / 'runs' / 'short-sweep' / 'iterations' / 'k000' / 'record.json').read_text())
    sweeps = record['info']['sweeps']
    assert 1 <= sweeps <= 3 and (sweeps == 1) == ('sweeping again to fill the gaps' not in out), out[-5000:]
    # a sweep that ran in full takes its 40 s and more; one stopped early less (the stop's own
    # latency included)
    assert 3.0 <= record['info']['plate_s'] < 40.0 + 41.0 * (sweeps - 1), record['info']
    # the bias went through the force_sensor node to the sensor (a refusal stops the iteration)
    # between the fans going off and the iteration's commands, and its spin-down is settle time
    stamps = record['timestamps']
    assert stamps['started'] < stamps['biased'] < stamps['applied'] < stamps['sweep_started'], stamps
    assert record['info']['settle_s'] >= 2 * 0.5, record['info']
    second = json.loads((tmp_path / 'runs' / 'short-sweep' / 'iterations' / 'k001' / 'record.json').read_text())
    stamps = second['timestamps']
    assert stamps['started'] < stamps['biased'] < stamps['applied'] < stamps['sweep_started'], stamps
