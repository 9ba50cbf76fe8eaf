"""`wind-shaper up --sim` as a real command: six node processes on the simulated rig, brought up,
used and stopped, with every child checked by PID."""
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]
NODES = ('sim_tunnel', 'fan_output', 'force_sensor', 'mocap_relay', 'field_estimator',
         'coordinator')
UP_LINE = re.compile(r'all (\d+) nodes are up in ([\d.]+) s \(pids: (.*)\)')


def alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    state = Path(f'/proc/{pid}/stat').read_text().split(')')[1].split()[0]
    return state != 'Z'


def children_of(pid):
    """PIDs whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / 'stat').read_text().split(')')[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out


class Up:
    """``wind-shaper up`` in a subprocess, its output collected line by line."""

    def __init__(self, env, cwd, *args):
        missing = [n for n in NODES if not (Path(__file__).resolve().parents[2] / 'wind_shaper'
                                             / 'nodes' / f'{n}.py').is_file()]
        assert not missing, f'node modules missing: {missing}'
        self.process = subprocess.Popen(
            [sys.executable, '-m', 'wind_shaper.cli.main', 'up', '--sim', *args], cwd=cwd,
            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True, start_new_session=True)
        self.lines = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.process.stdout:
            self.lines.append(line.rstrip('\n'))

    def output(self):
        return '\n'.join(self.lines)

    def wait_line(self, pattern, timeout_s):
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for line in list(self.lines):
                m = regex.search(line)
                if m:
                    return m
            if self.process.poll() is not None and not self._reader.is_alive():
                break
            time.sleep(0.1)
        pytest.fail(f'no line matching {pattern!r} within {timeout_s} s; output:\n'
                    f'{self.output()[-6000:]}')

    def wait(self, timeout_s):
        try:
            code = self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            pytest.fail(f'wind-shaper up did not end within {timeout_s} s; output:\n'
                        f'{self.output()[-6000:]}')
        self._reader.join(5.0)
        return code

    def kill(self):
        if self.process.poll() is None:
            self.process.kill()   # its nodes get SIGTERM (parent-death signal)
            self.process.wait(10)


@pytest.fixture
def up(ros_env, tmp_path):
    started = []

    def start(*args):
        u = Up(ros_env, tmp_path, *args)
        started.append(u)
        return u
    yield start
    for u in started:
        u.kill()


def node_pids(match):
    pids = dict(item.rsplit(' ', 1) for item in match.group(3).split(', '))
    return {name: int(pid) for name, pid in pids.items()}


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
    u = up('--iterations', '3', '--target', 'parabolic', '--run-name', 'graph-test',
           '--set', 'coordinator.sweep_duration_s=5.0', '--set', 'coordinator.settle_s=0.5')
    assert u.wait(280) == 0, u.output()[-6000:]
    out = u.output()
    rmse = [float(x) for x in re.findall(r'k=\s*\d+\s+RMSE ([\d.]+) N', out)]
    assert len(rmse) == 3, out[-4000:]
    run = tmp_path / 'runs' / 'graph-test'
    assert (run / 'run.yaml').is_file() and (run / 'iterations' / 'k002' / 'record.json').is_file()
    report = json.loads((run / 'report' / 'run.json').read_text())
    errors = [it['rmse_N'] for it in report['iterations']]
    assert errors == pytest.approx(rmse, abs=1e-3)
    assert errors[-1] < 0.7 * errors[0], f'the error did not fall: {errors}'
    for png in ('field_maps.png', 'error.png', 'pwm.png'):
        assert (run / 'report' / png).stat().st_size > 1000
    print(f'RMSE per iteration through the graph: {errors}')
