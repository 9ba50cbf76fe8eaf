"""Driving `wind-shaper up --sim` from tests: the command in a subprocess with its output
collected, and the node processes it starts, found by PID. Used by test_up and test_faults."""
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

NODES = ('sim_tunnel', 'fan_output', 'force_sensor', 'mocap_relay', 'field_estimator',
         'coordinator')
UP_LINE = re.compile(r'all (\d+) nodes are up in ([\d.]+) s \(pids: (.*)\)')
#: the supervisor's line for a restarted node, with its new pid
RESTART_PID = re.compile(r'wind-shaper up: restarting \S+ \(\d+ of \d+\): pid (\d+)')
#: the simulated motion capture's pose rate in the graph tier [Hz] (the sim's own default is
#: 100; the in-process simulator samples at 50): the graph at rest costs rclpy's executor about
#: 1 ms of CPU per message, and at 50 poses a second it took 49 % of a core instead of 74 %
#: (one run each, 2026-11-28), which the CPU-bound lane running beside the graph tier gets back
GRAPH_MOCAP_RATE_HZ = 50.0


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


def free_udp_ports(n):
    """n UDP ports that are free on loopback now."""
    sockets = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    try:
        for sock in sockets:
            sock.bind(('127.0.0.1', 0))
        return [sock.getsockname()[1] for sock in sockets]
    finally:
        for sock in sockets:
            sock.close()


class Up:
    """``wind-shaper up`` in a subprocess, its output collected line by line. The simulated rig's
    MAVLink and Net F/T ports are free ones, so a graph someone runs on the default ports (a
    demo) does not collide with the test's."""

    def __init__(self, env, cwd, *args, sim=True, prefix=(), options=(),
                 mocap_rate_hz=GRAPH_MOCAP_RATE_HZ):
        """sim: start the simulated rig (``--sim``) on free ports, its motion capture sending
        ``mocap_rate_hz`` poses a second (None: the sim's own rate); prefix: what runs the
        command (``ip netns exec HOST`` for a host of its own); options: the command's global
        options (``--namespace NS``)."""
        missing = [n for n in NODES if not (Path(__file__).resolve().parents[2] / 'wind_shaper'
                                             / 'nodes' / f'{n}.py').is_file()]
        assert not missing, f'node modules missing: {missing}'
        sim_args = []
        if sim:
            mavlink, netft = free_udp_ports(2)
            sim_args = ['--sim', '--set', f'sim_tunnel.mavlink_port={mavlink}',
                        '--set', f'fan_output.mavlink_url=udpout:127.0.0.1:{mavlink}',
                        '--set', f'sim_tunnel.netft_port={netft}',
                        '--set', f'force_sensor.sensor_port={netft}']
            if mocap_rate_hz is not None:
                sim_args += ['--set', f'sim_tunnel.mocap_rate_hz={mocap_rate_hz}']
        self.process = subprocess.Popen(
            [*prefix, sys.executable, '-m', 'wind_shaper.cli.main', *options, 'up', *sim_args, *args],
            cwd=cwd,
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

    def node_pids_named(self):
        """Every node PID the output named: the start line's and each restart's."""
        pids = set()
        for line in list(self.lines):
            m = UP_LINE.search(line)
            if m:
                pids.update(node_pids(m).values())
            pids.update(int(x) for x in RESTART_PID.findall(line))
        return pids

    def kill(self, grace_s=10.0):
        """End the graph: SIGINT (up stops its nodes as after Ctrl-C), SIGKILL after
        ``grace_s``; then SIGKILL every node process (and its process group: the estimate
        worker) the output named that is still running. A node left behind by a killed
        supervisor once kept a core busy for the rest of a CI run."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(grace_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(10)
        for pid in self.node_pids_named():
            try:
                if alive(pid) and 'wind_shaper' in Path(f'/proc/{pid}/cmdline').read_text():
                    os.killpg(pid, signal.SIGKILL)   # each node leads its own session
            except (OSError, ValueError):
                pass


def node_pids(match):
    pids = dict(item.rsplit(' ', 1) for item in match.group(3).split(', '))
    return {name: int(pid) for name, pid in pids.items()}
