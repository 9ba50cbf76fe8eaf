"""The process supervisor behind `wind-shaper up` (wind_shaper.supervisor), with small Python
scripts standing in for nodes: no ROS here."""
import io
import os
import signal
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
import yaml

from wind_shaper.supervisor import (CONFIG_ERROR_EXIT, GraphError, NodeGaveUp, NodeSpec,
                                    RestartPolicy, Stopped, StopSignals, Supervisor, format_value,
                                    graph_env, node_command, plan_graph)

QUICK = RestartPolicy(backoff_s=0.05, max_backoff_s=0.2)


def gone(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return Path(f'/proc/{pid}/stat').read_text().split(')')[1].split()[0] == 'Z'


def wait_for(predicate, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


@pytest.fixture
def script(tmp_path):
    """script(name, body) -> NodeSpec running ``body`` (Python) as the node ``name``."""
    def make(name, body):
        path = tmp_path / f'{name}.py'
        path.write_text(textwrap.dedent(body))
        return NodeSpec(name, (sys.executable, '-u', str(path)))
    return make


@pytest.fixture
def supervisors():
    """make(specs, **kw) -> Supervisor writing into a StringIO; every one is shut down after."""
    made = []

    def make(specs, **kw):
        kw.setdefault('env', dict(os.environ))
        kw.setdefault('grace_s', 2.0)
        sup = Supervisor(specs, out=io.StringIO(), **kw)
        made.append(sup)
        return sup
    yield make
    for sup in made:
        sup.shutdown(0.5)
        assert all(gone(pid) for pid in sup.all_pids())


#: A well-behaved child: it says hello from inside its clean path, so that a SIGINT sent as soon
#: as the hello is read cannot land between the two (a loaded machine once put it there).
RUNS = '''
import signal, sys, time
try:
    print("hello from", sys.argv[0].split("/")[-1], flush=True)
    while True:
        time.sleep(0.05)
except KeyboardInterrupt:
    print("bye", flush=True)
'''


# ------------------------------------------------------------------------- planning
def write_params(folder, node, params):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f'{node}.yaml').write_text(yaml.safe_dump({node: {'ros__parameters': params}}))


def test_plan_graph_params_files_fallback_and_overrides(tmp_path):
    mine, shipped = tmp_path / 'mine', tmp_path / 'shipped'
    write_params(mine, 'coordinator', {'config_dir': '', 'sweep_duration_s': 20.0, 'run_name': 'x'})
    write_params(shipped, 'fan_output', {'flavour': 'ardupilot_servo'})
    write_params(shipped, 'coordinator', {'config_dir': ''})
    specs = plan_graph(['fan_output', 'coordinator'], mine, fallback_dir=shipped,
                       overrides={'coordinator': {'sweep_duration_s': 3, 'run_name': 'r1'}},
                       python='py')
    fan, coord = specs
    assert fan.params_file == shipped / 'fan_output.yaml' and 'no fan_output.yaml' in fan.note
    assert 'config_dir' not in ' '.join(fan.argv)       # fan_output does not declare it
    assert coord.note == ''
    assert coord.argv == ('py', '-m', 'wind_shaper.nodes.coordinator', '--ros-args',
                          '--params-file', str(mine.resolve() / 'coordinator.yaml'),
                          '-p', f'config_dir:={mine.resolve()}',
                          '-p', 'sweep_duration_s:=3.0',   # an int for a float parameter
                          '-p', 'run_name:=r1')
    with pytest.raises(GraphError, match="no parameter 'sweep_s'.*sweep_duration_s"):
        plan_graph(['coordinator'], mine, overrides={'coordinator': {'sweep_s': 3}})
    with pytest.raises(GraphError, match='not in the graph'):
        plan_graph(['coordinator'], mine, overrides={'coordinatr': {'run_name': 'a'}})
    with pytest.raises(GraphError, match='put a force_sensor.yaml in'):
        plan_graph(['force_sensor'], mine, fallback_dir=shipped)


def test_the_shipped_config_has_a_params_file_per_node():
    from wind_shaper.core.config import default_config_dir
    from wind_shaper.ros import names
    nodes = [names.SIM_TUNNEL, *names.GRAPH_NODES]
    missing = [n for n in nodes if not (default_config_dir() / f'{n}.yaml').is_file()]
    assert not missing, f'node configs missing: {missing}'
    specs = plan_graph(nodes, default_config_dir())
    assert [s.name for s in specs] == nodes


def test_values_are_written_the_way_ros_args_read_them():
    assert format_value(3.0) == '3.0' and format_value(True) == 'true' and format_value(7) == '7'
    assert format_value('parabolic') == 'parabolic'
    assert format_value([1, 2]) == '[1, 2]' and format_value(['a', 'b']) == "['a', 'b']"
    assert yaml.safe_load(format_value([0.5, -1e-3])) == [0.5, -1e-3]
    assert node_command('x', None, {'a': 1}, python='py') == [
        'py', '-m', 'wind_shaper.nodes.x', '--ros-args', '-p', 'a:=1']


def test_discovery_stays_local_unless_the_user_chose():
    assert graph_env({})['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    chosen = graph_env({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'})
    assert chosen['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'
    assert 'ROS_AUTOMATIC_DISCOVERY_RANGE' not in graph_env({'ROS_LOCALHOST_ONLY': '0'})
    assert graph_env({})['PYTHONUNBUFFERED'] == '1'


def test_the_graph_talks_over_udp_unless_the_user_chose_the_transports():
    # a node restarted after SIGKILL can stay deaf on Fast DDS's shared memory
    assert graph_env({})['FASTDDS_BUILTIN_TRANSPORTS'] == 'UDPv4'
    assert graph_env({'FASTDDS_BUILTIN_TRANSPORTS': 'SHM'})['FASTDDS_BUILTIN_TRANSPORTS'] == 'SHM'


def test_restart_backoff_doubles_up_to_a_cap():
    p = RestartPolicy(backoff_s=1.0, max_backoff_s=5.0)
    assert [p.delay(n) for n in range(5)] == [1.0, 2.0, 4.0, 5.0, 5.0]


# ------------------------------------------------------------------------- running
def test_output_is_prefixed_and_shutdown_leaves_nothing_running(script, supervisors, tmp_path):
    sup = supervisors([script('alpha', RUNS), script('b', RUNS)], log_dir=tmp_path / 'logs')
    sup.start()
    assert wait_for(lambda: len(sup.tail('alpha')) and len(sup.tail('b')))
    pids = sup.pids()
    assert set(pids) == {'alpha', 'b'}
    codes = sup.shutdown()
    assert codes == {'alpha': 0, 'b': 0}                     # SIGINT: their clean path
    assert all(gone(pid) for pid in pids.values())
    out = sup.out.getvalue()
    assert '[alpha] hello from alpha.py' in out and '[b    ] hello from b.py' in out
    assert '[alpha] bye' in out
    log = (tmp_path / 'logs' / 'alpha.log').read_text().splitlines()
    assert log == ['hello from alpha.py', 'bye']


def test_a_child_that_ignores_sigint_is_killed_after_the_grace_period(script, supervisors):
    stubborn = script('stubborn', '''
        import signal, time
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        print("ready", flush=True)
        while True:
            time.sleep(0.05)
    ''')
    sup = supervisors([stubborn], grace_s=0.5)
    sup.start()
    assert wait_for(lambda: sup.tail('stubborn') == ['ready'])
    pid = sup.pids()['stubborn']
    t0 = time.monotonic()
    assert sup.shutdown() == {'stubborn': -signal.SIGKILL}
    assert 0.4 < time.monotonic() - t0 < 3.0
    assert gone(pid) and 'did not stop within 0.5 s' in sup.out.getvalue()


def test_wait_visible_returns_when_every_node_is_seen(script, supervisors):
    sup = supervisors([script('a', RUNS), script('b', RUNS)])
    sup.start()
    t0 = time.monotonic()
    seen = lambda: ['a'] + (['b'] if time.monotonic() - t0 > 0.3 else [])   # noqa: E731
    assert 0.3 <= sup.wait_visible(seen, timeout_s=5.0) < 2.0


def test_a_node_that_never_appears_is_named_with_its_log(script, supervisors):
    sup = supervisors([script('a', RUNS), script('shy', RUNS)])
    sup.start()
    with pytest.raises(GraphError) as err:
        sup.wait_visible(lambda: ['a'], timeout_s=0.5)
    assert 'node shy did not appear in the ROS graph within 0.5 s' in str(err.value)
    assert 'hello from shy.py' in str(err.value)


def test_a_stop_request_ends_the_start_up_wait_at_once(script, supervisors):
    sup = supervisors([script('a', RUNS)])
    sup.start()
    t0 = time.monotonic()
    with pytest.raises(Stopped):
        sup.wait_visible(lambda: [], timeout_s=30.0,
                         should_stop=lambda: time.monotonic() - t0 > 0.2)
    assert time.monotonic() - t0 < 2.0


def test_a_node_that_dies_at_start_up_is_reported_with_exit_code_and_tail(script, supervisors):
    sup = supervisors([script('a', RUNS), script('broken', '''
        print("loading", flush=True)
        raise SystemExit("ModuleNotFoundError: no module named wind_shaper.nodes.broken")
    ''')])
    sup.start()
    with pytest.raises(GraphError) as err:
        sup.wait_visible(lambda: [], timeout_s=10.0)
    msg = str(err.value)
    assert 'node broken exited with code 1' in msg and 'loading' in msg
    assert 'ModuleNotFoundError' in msg


def test_a_crashing_node_is_restarted_with_backoff_then_given_up(script, supervisors):
    crash = script('crash', '''
        import time
        print("up", flush=True)
        time.sleep(0.1)
        raise SystemExit(3)
    ''')
    sup = supervisors([crash, script('steady', RUNS)], policy=QUICK)
    sup.start()
    steady_pid = sup.pids()['steady']
    with pytest.raises(NodeGaveUp, match='crash exited with code 3.*restarted 3 times'):
        sup.supervise(lambda: False, interval_s=0.02)
    out = sup.out.getvalue()
    assert out.count('exited with code 3') == 4 and 'restarting crash (3 of 3)' in out
    assert len(sup.all_pids()) == 4 + 1          # 1 start + 3 restarts, and steady
    assert sup.pids()['steady'] == steady_pid                  # the others are left alone


def test_config_errors_and_disabled_restarts_give_up_at_once(script, supervisors):
    bad = script('bad', f'print("error: x", flush=True); raise SystemExit({CONFIG_ERROR_EXIT})')
    sup = supervisors([bad], policy=QUICK)
    sup.start()
    with pytest.raises(NodeGaveUp, match='configuration error'):
        sup.supervise(lambda: False, interval_s=0.02)
    assert 'error: x' in sup.out.getvalue() and len(sup.all_pids()) == 1

    dies = script('dies', 'raise SystemExit(1)')
    sup = supervisors([dies], policy=RestartPolicy(enabled=False))
    sup.start()
    with pytest.raises(NodeGaveUp, match='restarts are off'):
        sup.supervise(lambda: False, interval_s=0.02)


def test_a_restarted_node_runs_again(script, supervisors, tmp_path):
    flag = tmp_path / 'crashed-once'
    once = script('once', f'''
        import pathlib, time
        flag = pathlib.Path({str(flag)!r})
        if not flag.exists():
            flag.write_text("x")
            raise SystemExit(-1)
        try:
            print("second life", flush=True)
            while True:
                time.sleep(0.05)
        except KeyboardInterrupt:
            pass
    ''')
    sup = supervisors([once], policy=QUICK)
    sup.start()
    t0 = time.monotonic()
    sup.supervise(lambda: 'second life' in sup.tail('once') or time.monotonic() - t0 > 5,
                  interval_s=0.02)
    assert 'second life' in sup.tail('once') and len(sup.all_pids()) == 2
    assert sup.shutdown() == {'once': 0}


BEATS = '''
import os, pathlib, sys, time
beat = pathlib.Path(os.environ["WIND_SHAPER_HEARTBEAT"])
hang_at = float(sys.argv[1]) if len(sys.argv) > 1 else float("inf")
t0 = time.monotonic()
try:
    print("beating", flush=True)
    while True:
        if time.monotonic() - t0 < hang_at:      # then stuck, as a blocked executor is
            beat.touch()
        time.sleep(0.05)
except KeyboardInterrupt:
    pass
'''


def test_a_hung_node_is_killed_and_restarted_and_a_beating_one_is_left_alone(script,
                                                                            supervisors):
    hangs = script('hangs', BEATS)
    hangs = NodeSpec(hangs.name, (*hangs.argv, '0.3'))     # beats for 0.3 s, then hangs
    sup = supervisors([hangs, script('beats', BEATS)],
                      policy=RestartPolicy(backoff_s=0.05, max_backoff_s=0.2, hang_after_s=1.5))
    sup.start()
    beating_pid = sup.pids()['beats']
    first = sup.pids()['hangs']
    t0 = time.monotonic()
    sup.supervise(lambda: len(sup.all_pids()) >= 3 or time.monotonic() - t0 > 20, interval_s=0.02)
    out = sup.out.getvalue()
    assert len(sup.all_pids()) == 3 and gone(first), out        # hangs restarted once
    assert 'node hangs (pid' in out and 'it is hung; killing it' in out, out
    assert 'restarting hangs (1 of 3)' in out
    assert sup.pids()['beats'] == beating_pid and 'node beats' not in out


def test_a_node_that_never_beats_is_hung_once_the_time_is_up(script, supervisors):
    silent = script('silent', RUNS)          # a process that never runs the node runner
    sup = supervisors([silent], policy=RestartPolicy(max_restarts=0, hang_after_s=1.0))
    sup.start()
    time.sleep(0.2)
    sup.poll()
    assert 'hung' not in sup.out.getvalue()              # not before hang_after_s
    with pytest.raises(NodeGaveUp, match='silent'):
        sup.supervise(lambda: False, interval_s=0.02)
    assert 'no heartbeat' in sup.out.getvalue()


def test_the_runner_beats_while_its_executor_spins(tmp_path):
    """The node runner touches the heartbeat file between executor slices."""
    from wind_shaper.core.heartbeat import Heartbeat
    beat = tmp_path / 'node'
    heart = Heartbeat(str(beat), period_s=0.0)
    heart.beat()
    first = beat.stat().st_mtime_ns
    time.sleep(0.02)
    heart.beat()
    assert beat.stat().st_mtime_ns > first
    Heartbeat(None).beat()                                  # not supervised: nothing to do


def test_children_die_with_a_killed_supervisor(tmp_path):
    """The parent-death signal: kill -9 the supervisor, its nodes get SIGTERM."""
    runner = tmp_path / 'runner.py'
    runner.write_text(textwrap.dedent('''
        import sys, time
        from wind_shaper.supervisor import NodeSpec, Supervisor
        spec = NodeSpec('child', (sys.executable, '-c', 'import time; time.sleep(60)'))
        sup = Supervisor([spec])
        sup.start()
        print(sup.pids()['child'], flush=True)
        time.sleep(60)
    '''))
    import subprocess
    proc = subprocess.Popen([sys.executable, str(runner)], stdout=subprocess.PIPE, text=True)
    try:
        child = int(proc.stdout.readline())
        proc.kill()
        proc.wait(5)
        assert wait_for(lambda: gone(child), 5.0), 'the child outlived its supervisor'
    finally:
        proc.kill()
        proc.wait(5)


def test_stop_signals_set_a_flag_instead_of_raising():
    previous = signal.getsignal(signal.SIGTERM)
    with StopSignals() as stop:
        assert not stop()
        os.kill(os.getpid(), signal.SIGTERM)
        assert wait_for(stop, 1.0) and stop.signal == signal.SIGTERM
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)
    assert signal.getsignal(signal.SIGTERM) is previous
    assert threading.current_thread() is threading.main_thread()


def test_the_graph_comes_up_in_stages(script, supervisors):
    sup = supervisors([script('rig', RUNS), script('driver', RUNS)])
    sup.start(['rig'])
    assert set(sup.pids()) == {'rig'}
    assert sup.wait_visible(lambda: ['rig'], timeout_s=2.0, names=['rig']) < 1.0
    sup.start()                                     # the rest
    assert set(sup.pids()) == {'rig', 'driver'}
    with pytest.raises(GraphError, match='no node'):
        sup.start(['nope'])


def test_a_deaf_node_is_killed_and_restarted_and_one_that_answers_is_left_alone(script,
                                                                               supervisors):
    """The probe (here a stand-in: 'talks' always answers, 'deaf' never) decides, not the
    heartbeat (off here); nobody is judged before deaf_after_s."""
    sup = supervisors([script('talks', RUNS), script('deaf', RUNS)],
                      policy=RestartPolicy(backoff_s=0.05, max_backoff_s=0.2, deaf_after_s=1.0))
    asked = []

    def probe(names):
        asked.append(list(names))
        return {'talks': sup.clock()}
    sup.watch_answers(probe)
    sup.start()
    talking, deaf = sup.pids()['talks'], sup.pids()['deaf']
    sup.poll()
    assert 'deaf' not in sup.out.getvalue().replace('node deaf', '')   # not before 1 s
    t0 = time.monotonic()
    sup.supervise(lambda: len(sup.all_pids()) >= 3 or time.monotonic() - t0 > 10, interval_s=0.02)
    out = sup.out.getvalue()
    assert len(sup.all_pids()) == 3 and gone(deaf), out
    assert 'node deaf (pid' in out and 'answered no call for 1 s (since it started' in out, out
    assert 'restarting deaf (1 of 3)' in out and sup.pids()['talks'] == talking, out
    assert ['talks', 'deaf'] in asked


def test_without_deaf_after_the_probe_is_not_asked(script, supervisors):
    sup = supervisors([script('quiet', RUNS)], policy=QUICK)
    sup.watch_answers(lambda names: pytest.fail('asked without deaf_after_s'))
    sup.start()
    sup.supervise(lambda: sup.clock() - sup._children['quiet'].started_at > 0.5, interval_s=0.02)
    assert len(sup.all_pids()) == 1
