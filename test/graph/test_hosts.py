"""The graph over three hosts, as a lab runs it: Linux network namespaces joined by veth pairs
through a bridge stand in for the tunnel PC (sim_tunnel, fan_output, force_sensor), the mocap PC
(mocap_relay) and the shaping PC (field_estimator, coordinator). DDS finds its peers over the
links (multicast discovery on the subnet, UDP only: no localhost setting, no shared memory), all
of it in the ROS namespace ``tunnel_b``. Then the tunnel PC's link is pulled in the middle of an
iteration: the fans go safe within fan_output's watchdog time, the iteration fails with the
cause, the samples received are kept in the journal, and once the link is back the next
iteration runs. Every namespace and link the module makes is removed, also when it fails."""
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from netns_required import require_netns
from up_driver import UP_LINE, Up

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'tools'))
from netns_hosts import Hosts  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NS = 'tunnel_b'
TAG = f'ws{os.getpid() % 100000}'     # netns and link names of this run
COMMAND_TIMEOUT_S = 2.0               # fan_output's watchdog (its shipped default)
#: the ROS log line of fan_output making the fans safe, with its wall-clock stamp
SAFE_LINE = re.compile(r'\[(\d+\.\d+)\] \[[\w.]*fan_output\]: fans safe \((watchdog|[^)]*)\)')


@pytest.fixture(scope='module')
def hosts():
    require_netns('the multi-host test')
    h = Hosts(TAG, f'10.77.{os.getpid() % 200 + 20}.')
    try:
        h.create()
        yield h
    finally:
        h.remove()


@pytest.fixture(scope='module')
def graph(hosts, tmp_path_factory, new_domain_id):
    root = tmp_path_factory.mktemp('hosts')
    env = dict(os.environ, ROS_DOMAIN_ID=new_domain_id(), ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET',
               FASTDDS_BUILTIN_TRANSPORTS='UDPv4')
    for key in ('ROS_LOCALHOST_ONLY', 'ROS_STATIC_PEERS', 'WIND_SHAPER_NAMESPACE'):
        env.pop(key, None)
    options = ('--namespace', NS)
    common = ('--startup-timeout', '90')
    ups = {}
    try:
        ups['tunnel'] = Up(env, root, *common, '--nodes', 'fan_output,force_sensor',
                           '--set', f'fan_output.command_timeout_s={COMMAND_TIMEOUT_S}',
                           prefix=hosts.exec(1), options=options)
        ups['mocap'] = Up(env, root, *common, '--nodes', 'mocap_relay', sim=False,
                          prefix=hosts.exec(2), options=options)
        ups['shaping'] = Up(env, root, *common, '--nodes', 'field_estimator,coordinator',
                            '--set', 'coordinator.settle_s=0.5',
                            '--set', 'coordinator.sweep_duration_s=8',
                            '--set', 'coordinator.service_timeout_s=6',
                            sim=False, prefix=hosts.exec(3), options=options)
        for u in ups.values():
            u.wait_line(UP_LINE.pattern, 120)
        yield root, env, hosts, ups
    finally:
        for u in ups.values():
            u.kill()


def cli(graph, host, *args, namespace=NS, timeout_s=180):
    root, env, hosts, _ = graph
    options = ('--namespace', namespace) if namespace else ()
    p = subprocess.run([*hosts.exec(host), sys.executable, '-m', 'wind_shaper.cli.main', *options,
                        *args], cwd=root, env=env, stdin=subprocess.DEVNULL, capture_output=True,
                       text=True, timeout=timeout_s)
    return p.returncode, p.stdout + p.stderr


def plant_pwm(graph, seconds=4.0):
    """The simulated plant's applied commands, as sim_tunnel reports them on /diagnostics, read
    on the tunnel host itself (it needs no link to the others)."""
    root, env, hosts, _ = graph
    code = ('import sys, time, rclpy\n'
            'from diagnostic_msgs.msg import DiagnosticArray\n'
            'rclpy.init(); n = rclpy.create_node("pwm_probe"); got = []\n'
            'n.create_subscription(DiagnosticArray, "/diagnostics", lambda m: got.extend(\n'
            '    [kv.value for s in m.status if "sim_tunnel" in s.name for kv in s.values if kv.key == "pwm"]), 10)\n'
            f't0 = time.time()\nwhile time.time() - t0 < {seconds} and not got:\n'
            '    rclpy.spin_once(n, timeout_sec=0.1)\n'
            'print(got[-1] if got else "none")\n')
    p = subprocess.run([*hosts.exec(1), sys.executable, '-c', code], env=env, capture_output=True,
                       text=True, timeout=seconds + 30)
    text = p.stdout.strip()
    return {k: float(v) for k, v in re.findall(r'(\w+)=([\d.]+)', text)}, text


@pytest.mark.timeout(420)
def test_the_graph_runs_over_three_hosts_in_its_namespace(graph):
    code, out = cli(graph, 3, 'iterate', '--wait', '40')
    assert code == 0 and 'RMSE' in out, out
    # a graph in a namespace keeps its own run folder (another tunnel's stays apart)
    assert (Path(graph[0]) / 'runs' / NS / 'default' / 'iterations').is_dir()
    # the commands reach the plant on the tunnel host
    pwm, text = plant_pwm(graph)
    assert pwm and max(pwm.values()) > 0.05, text
    # another namespace (here the default one) sees no coordinator: two tunnels can share a domain
    code, out = cli(graph, 3, 'status', '--wait', '3', namespace=None)
    assert code == 2 and 'no coordinator status on /wind_shaper/iteration/status' in out, out
    code, out = cli(graph, 2, 'status', '--wait', '10')
    assert code == 0, out


@pytest.mark.timeout(600)
def test_pulling_the_tunnel_hosts_link_mid_iteration_fails_it_safely_and_the_next_one_runs(graph):
    root, env, hosts, ups = graph
    journal = Path(root) / 'runs' / 'journal' / NS   # a namespaced graph's own journal
    before = {p.name for p in journal.glob('sweep-*')} if journal.is_dir() else set()
    call = subprocess.Popen([*hosts.exec(3), sys.executable, '-m', 'wind_shaper.cli.main',
                             '--namespace', NS, 'iterate', '--wait', '40'], cwd=root, env=env,
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    down_at = None
    try:
        # the sweep is under way: samples arrive in a new journal folder
        deadline = time.monotonic() + 90
        folder = None
        while folder is None:
            assert time.monotonic() < deadline and call.poll() is None, call.stdout.read()
            new = [p for p in journal.glob('sweep-*') if p.name not in before] if journal.is_dir() else []
            if new and (new[0] / 'force.f64').is_file() and (new[0] / 'force.f64').stat().st_size > 16 * 200:
                folder = new[0]
            time.sleep(0.1)
        safe_lines_before = len(SAFE_LINE.findall(ups['tunnel'].output()))
        down_at = time.time()
        hosts.link(1, up=False)
        kept = (folder / 'force.f64').stat().st_size // 16
        out, _ = call.communicate(timeout=120)
    finally:
        if call.poll() is None:
            call.kill()
            call.wait(10)
    try:
        # the fans went safe on the tunnel host within the watchdog time
        safe = [(float(t), why) for t, why in SAFE_LINE.findall(ups['tunnel'].output())][safe_lines_before:]
        assert safe, ups['tunnel'].output()[-4000:]
        took = safe[0][0] - down_at
        print(f'fans safe {took:.2f} s after the link went down (watchdog {COMMAND_TIMEOUT_S} s)')
        assert took <= COMMAND_TIMEOUT_S + 1.0, (took, safe[0])
        pwm, text = plant_pwm(graph)
        assert pwm and max(pwm.values()) == 0.0, text
        # the iteration failed and said why
        assert call.returncode != 0, out
        assert re.search(r'did not answer|read-back|failed', out), out
    finally:
        hosts.link(1, up=True)
    # the samples received before the link went down are in the journal
    force = (folder / 'force.f64').stat().st_size // 16
    assert force >= kept > 200
    # once the link is back, the next iteration runs
    deadline = time.monotonic() + 120
    while True:
        code, out = cli(graph, 3, 'iterate', '--wait', '40')
        if code == 0 or time.monotonic() > deadline:
            break
        time.sleep(2.0)
    assert code == 0 and 'RMSE' in out, out
    assert (folder / 'outcome').read_text().strip() == 'abandoned'
