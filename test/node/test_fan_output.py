"""fan_output in-process against the loopback SimAutopilot (real MAVLink over UDP)."""
import math
import threading
import time
from dataclasses import fields
from pathlib import Path

import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from wind_shaper_msgs.msg import FanCommand  # noqa: E402

from wind_shaper.core.errors import ConfigError  # noqa: E402
from wind_shaper.nodes.fan_output import FanOutputNode, FanOutputParams  # noqa: E402
from wind_shaper.ros import names, qos  # noqa: E402
from wind_shaper.sim import SimAutopilot  # noqa: E402

from waiting import wait_for  # noqa: E402

pytestmark = pytest.mark.ros
CONFIG = Path(__file__).resolve().parents[2] / 'config' / 'fan_output.yaml'
FANS = ['a', 'b', 'c']
CHANNELS = [3, 5, 1]
SAFE = {ch: 1000 for ch in range(1, 17)}


class Harness:
    """The node under test and a client node, spun by one executor on a background thread."""

    def __init__(self, context):
        self.context = context
        self.executor = SingleThreadedExecutor(context=context)
        self.client = rclpy.create_node('fan_output_test_client', context=context)
        self.executor.add_node(self.client)
        self.nodes = []
        self.applied, self.diagnostics = [], []
        self.pub = self.client.create_publisher(FanCommand, names.FAN_COMMAND, qos.COMMAND)
        self.client.create_subscription(FanCommand, names.FAN_APPLIED, self.applied.append,
                                        qos.LATCHED)
        self.client.create_subscription(DiagnosticArray, names.DIAGNOSTICS,
                                        self.diagnostics.append, 10)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def start(self, autopilot, **overrides):
        params = dict(fan_names=FANS, channels=CHANNELS, mavlink_url=autopilot.url,
                      slew_rate_per_s=100.0, heartbeat_timeout_s=0.5, send_rate_hz=50.0)
        params.update(overrides)
        node = FanOutputNode(context=self.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def command(self, pwm, fans=FANS):
        self.pub.publish(FanCommand(names=list(fans), pwm=[float(u) for u in pwm]))

    def call(self, service, timeout_s=3.0):
        client = self.client.create_client(Trigger, service)
        try:
            assert client.wait_for_service(timeout_sec=timeout_s), f'{service} not available'
            future = client.call_async(Trigger.Request())
            assert wait_for(future.done, timeout_s), f'{service} did not answer'
            return future.result()
        finally:
            self.client.destroy_client(client)

    def diag_values(self):
        for msg in reversed(self.diagnostics):
            for status in msg.status:
                if status.name.startswith(names.FAN_OUTPUT):
                    return {kv.key: kv.value for kv in status.values} | {
                        '_level': status.level, '_message': status.message}
        return None

    def fresh_diag(self, timeout_s=2.5):
        """The next diagnostics report of fan_output."""
        self.diagnostics.clear()
        return wait_for(self.diag_values, timeout_s)

    def close(self):
        self.executor.shutdown(timeout_sec=2.0)
        self.thread.join(timeout=5.0)
        for node in self.nodes:
            node.destroy_node()
        self.client.destroy_node()


@pytest.fixture
def harness(ros_context):
    h = Harness(ros_context)
    yield h
    h.close()


@pytest.fixture
def autopilot():
    ap = SimAutopilot(heartbeat_hz=20.0, servo_output_hz=20.0)
    yield ap
    ap.close()


def outputs_are(autopilot, expected):
    return lambda: all(autopilot.outputs()[ch] == us for ch, us in expected.items())


def start_at(harness, autopilot, pwm=(0.2, 0.5, 0.9), **overrides):
    """Start the node, wait for the link, command ``pwm`` and wait until it is applied."""
    node = harness.start(autopilot, **overrides)
    expected = {ch: round(1000 + 1000 * u) for ch, u in zip(CHANNELS, pwm)}
    deadline = time.monotonic() + 5.0
    while not outputs_are(autopilot, expected)() and time.monotonic() < deadline:
        harness.command(pwm)   # repeat: the subscription may not be matched yet
        time.sleep(0.1)
    assert outputs_are(autopilot, expected)(), autopilot.outputs()
    return node


@pytest.mark.parametrize('flavour', ['ardupilot_servo', 'ardupilot_rc_override', 'px4_actuator'])
def test_command_reaches_the_autopilot_and_comes_back_applied(harness, flavour):
    with SimAutopilot(flavour=flavour, heartbeat_hz=20.0, servo_output_hz=20.0) as ap:
        start_at(harness, ap, (0.2, 0.5, 0.9), flavour=flavour)
        out = ap.outputs()
        assert (out[3], out[5], out[1]) == (1200, 1500, 1900)
        assert all(out[ch] == 1000 for ch in out if ch not in CHANNELS)   # others untouched

        def applied_matches():
            return any(list(m.names) == FANS and all(
                math.isclose(a, b, abs_tol=1e-9) for a, b in zip(m.pwm, (0.2, 0.5, 0.9)))
                for m in harness.applied)
        assert wait_for(applied_matches), harness.applied[-1:]


@pytest.mark.fault
def test_out_of_range_is_clipped_and_reported(harness, autopilot, fault_row):
    start_at(harness, autopilot, (0.3, 0.3, 0.3), u_min=0.1, u_max=0.8)
    harness.command((0.95, 0.05, 0.5))
    assert wait_for(outputs_are(autopilot, {3: 1800, 5: 1100, 1: 1500})), autopilot.outputs()
    assert wait_for(lambda: harness.applied and math.isclose(harness.applied[-1].pwm[0], 0.8))
    values = wait_for(lambda: (v := harness.fresh_diag()) and v['clipped'] == '1' and v)
    assert values and values['last_clipped'] == 'a,b', harness.diag_values()
    fault_row('fan command outside the configured [u_min, u_max]',
              'clipped to the configured range before sending, reported in /diagnostics', True)


@pytest.mark.fault
def test_malformed_commands_change_nothing(harness, autopilot, fault_row):
    start_at(harness, autopilot, (0.2, 0.5, 0.9), command_timeout_s=30.0)
    before = autopilot.outputs()
    # start_at repeats its command until the link shows it, so count what it sent
    accepted = wait_for(lambda: (v := harness.fresh_diag()) and v['commands'])
    assert accepted and int(accepted) >= 1, harness.diag_values()
    harness.command((0.1, 0.1, 0.1), fans=['a', 'b', 'x'])            # unknown fan
    harness.command((0.1, 0.1), fans=FANS)                             # length mismatch
    harness.pub.publish(FanCommand(names=['a', 'b'], pwm=[0.1, 0.1]))  # a fan missing
    harness.command((0.1, math.nan, 0.1))                              # NaN
    harness.command((0.1, 0.1, 0.1), fans=['a', 'a', 'b'])            # a fan twice
    values = wait_for(lambda: (v := harness.fresh_diag()) and v['rejected'] == '5' and v)
    assert values, harness.diag_values()
    assert values['commands'] == accepted and values['_level'] == b'\x01'
    time.sleep(0.2)
    assert autopilot.outputs() == before
    fault_row('malformed FanCommand: NaN/inf, unknown or missing fan names, length mismatch',
              'refused with the reason; the outputs do not change', True)


@pytest.mark.fault
def test_slew_limit(harness, autopilot, fault_row):
    log = []
    autopilot.on_outputs = lambda out: log.append((time.monotonic(), out[3]))
    start_at(harness, autopilot, (0.0, 0.0, 0.0), slew_rate_per_s=1.0)
    log.clear()
    t0 = time.monotonic()
    harness.command((0.6, 0.0, 0.0))
    assert wait_for(lambda: autopilot.outputs()[3] == 1600, 3.0)
    took = time.monotonic() - t0
    assert took >= 0.55, f'0 -> 0.6 at 1/s took only {took:.2f} s'
    assert len({us for _, us in log}) >= 10          # a ramp, not a step
    for i, (ti, ui) in enumerate(log):
        for tj, uj in log[i + 1:]:
            if tj - ti >= 0.2:
                assert (uj - ui) / (tj - ti) <= 1000 * 1.0 * 1.3, (ti, ui, tj, uj)
    assert all(b >= a for (_, a), (_, b) in zip(log, log[1:]))
    fault_row('a step command from 0 to full',
              'slewed at slew_rate_per_s, never a jump', True)


@pytest.mark.fault
def test_heartbeat_loss_makes_safe_and_a_new_command_resumes(harness, autopilot, fault_row):
    start_at(harness, autopilot, (0.2, 0.5, 0.9), command_timeout_s=30.0)
    autopilot.pause_heartbeat()
    assert wait_for(outputs_are(autopilot, SAFE), 2.0), autopilot.outputs()
    # a report on its way when the link dropped may still say up: wait for the next ones
    values = wait_for(lambda: (v := harness.fresh_diag()) and v['link'] == 'down' and v, 3.0)
    assert values and values['_level'] == b'\x02', harness.fresh_diag()
    autopilot.resume_heartbeat()
    assert wait_for(lambda: harness.fresh_diag()['link'] == 'up', 3.0)
    time.sleep(0.3)
    assert outputs_are(autopilot, SAFE)()      # the old command does not come back by itself
    harness.command((0.4, 0.4, 0.4))
    assert wait_for(outputs_are(autopilot, {3: 1400, 5: 1400, 1: 1400}))
    fault_row('autopilot heartbeat stops (heartbeat_timeout_s)',
              'fans safe; resume only on a new command', True)


@pytest.mark.fault
def test_cut_link_resends_safe_when_the_link_returns(harness, autopilot, fault_row):
    start_at(harness, autopilot, (0.2, 0.5, 0.9), command_timeout_s=30.0)
    autopilot.cut_link()                   # the safe pulse sent at the loss cannot arrive
    assert wait_for(lambda: harness.fresh_diag()['link'] == 'down', 3.0)
    assert autopilot.outputs()[1] == 1900
    autopilot.restore_link()
    assert wait_for(outputs_are(autopilot, SAFE), 3.0), autopilot.outputs()
    fault_row('MAVLink link cut both ways (pulled cable)',
              'link loss detected, fans safe; the safe pulse sent again when the link returns', True)


@pytest.mark.fault
def test_an_autopilot_that_forgot_the_outputs_gets_them_again(harness, autopilot, fault_row):
    # the read-back check alone (no periodic refresh): the mismatch makes fan_output resend
    start_at(harness, autopilot, (0.2, 0.5, 0.9), command_timeout_s=30.0, refresh_s=0.0)
    expected = {ch: round(1000 + 1000 * u) for ch, u in zip(CHANNELS, (0.2, 0.5, 0.9))}
    autopilot.reboot()                     # outputs back to safe, heartbeats go on
    assert outputs_are(autopilot, SAFE)()
    for _ in range(40):                    # the coordinator republishes the same command
        harness.command((0.2, 0.5, 0.9))
        if outputs_are(autopilot, expected)():
            break
        time.sleep(0.1)
    assert outputs_are(autopilot, expected)(), autopilot.outputs()
    assert int(harness.fresh_diag()['resyncs']) == 1
    fault_row('autopilot restarts (outputs reset, heartbeats go on)',
              'read-back mismatch seen, commands sent again', True)


@pytest.mark.fault
def test_watchdog_makes_safe_unless_commands_keep_coming(harness, autopilot, fault_row):
    start_at(harness, autopilot, (0.2, 0.5, 0.9), command_timeout_s=0.5)
    for _ in range(10):                    # republished at 5 Hz: stays on for 1 s
        harness.command((0.2, 0.5, 0.9))
        time.sleep(0.1)
        assert autopilot.outputs()[1] == 1900
    t_last = time.monotonic()
    harness.command((0.2, 0.5, 0.9))
    assert wait_for(outputs_are(autopilot, SAFE), 2.0)
    assert time.monotonic() - t_last >= 0.45
    assert wait_for(lambda: harness.fresh_diag()['watchdog_trips'] == '1', 3.0)
    fault_row('commands stop arriving (command_timeout_s)',
              'watchdog makes the fans safe', True)


@pytest.mark.fault
def test_emergency_stop_latches_until_reset(harness, autopilot, fault_row):
    start_at(harness, autopilot, (0.6, 0.6, 0.6), slew_rate_per_s=0.5)   # a ramp takes 1.2 s
    t0 = time.monotonic()
    assert harness.call(names.EMERGENCY_STOP).success
    # not slewed: sooner than the 1.2 s ramp down, with room for a busy machine's latency
    assert wait_for(outputs_are(autopilot, SAFE), 1.0)
    assert time.monotonic() - t0 < 1.0
    for _ in range(5):
        harness.command((0.3, 0.3, 0.3))
        time.sleep(0.1)
    assert outputs_are(autopilot, SAFE)()
    values = wait_for(lambda: (v := harness.fresh_diag()) and v['rejected'] == '5' and v, 3.0)
    assert values and values['estop'] == 'true', harness.fresh_diag()
    assert harness.call(names.RESET_STOP).success
    time.sleep(0.2)
    assert outputs_are(autopilot, SAFE)()      # reset alone does not restart the fans
    harness.command((0.3, 0.3, 0.3))
    assert wait_for(lambda: autopilot.outputs()[1] > 1000, 1.0)
    fault_row('emergency stop service',
              'all fans safe at once, latched: commands refused until reset_stop', True)


@pytest.mark.fault
def test_destroy_node_makes_safe(harness, autopilot, fault_row):
    node = start_at(harness, autopilot, (0.2, 0.5, 0.9), command_timeout_s=30.0)
    harness.executor.remove_node(node)
    harness.nodes.remove(node)
    node.destroy_node()
    assert wait_for(outputs_are(autopilot, SAFE), 1.0), autopilot.outputs()
    fault_row('fan_output shut down (SIGINT/SIGTERM path: destroy_node)',
              'safe pulse sent before the link closes', True)


@pytest.mark.fault
def test_exception_in_a_callback_makes_safe(harness, autopilot, fault_row):
    node = start_at(harness, autopilot, (0.2, 0.5, 0.9), command_timeout_s=30.0)

    def broken(*args):
        raise RuntimeError('injected')
    node._map.command = broken          # the send timer's next conversion raises
    harness.command((0.3, 0.3, 0.3))
    assert wait_for(outputs_are(autopilot, SAFE), 2.0), autopilot.outputs()
    # a command that arrives after the failure (republished, or delivered late on a busy
    # machine) is tried again, fails again and makes the fans safe again: each failure counts
    assert int(harness.fresh_diag()['exceptions']) >= 1
    fault_row('an exception inside a fan_output callback',
              'fans safe, the error logged, the node goes on', True)


def test_lifecycle_without_autostart(harness, autopilot):
    node = harness.start(autopilot, autostart=False)
    harness.command((0.5, 0.5, 0.5))
    time.sleep(0.3)
    assert outputs_are(autopilot, SAFE)() and autopilot.peer is None   # no link yet
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    harness.command((0.5, 0.5, 0.5))
    assert wait_for(outputs_are(autopilot, {3: 1500, 5: 1500, 1: 1500}))
    assert node.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
    assert wait_for(outputs_are(autopilot, SAFE), 1.0)
    harness.command((0.5, 0.5, 0.5))
    time.sleep(0.3)
    assert outputs_are(autopilot, SAFE)()
    assert node.trigger_cleanup() == TransitionCallbackReturn.SUCCESS


def test_bad_parameters_are_refused(ros_context):
    for overrides, match in (([Parameter('channels', value=[1, 2])], 'channels'),
                             ([Parameter('signing_key_hex', value='abc')], 'signing_key_hex'),
                             ([Parameter('flavour', value='px3')], 'flavour'),
                             ([Parameter('safe_us', value=900)], 'safe_us')):
        with pytest.raises(ConfigError, match=match):
            FanOutputNode(context=ros_context, parameter_overrides=overrides)


def test_config_file_lists_every_parameter(ros_context):
    listed = yaml.safe_load(CONFIG.read_text())['fan_output']['ros__parameters']
    assert set(listed) == {f.name for f in fields(FanOutputParams)}
    node = FanOutputNode(context=ros_context, cli_args=['--ros-args', '--params-file', str(CONFIG),
                                                        '-p', 'autostart:=false'])
    try:
        assert node.params == FanOutputParams(autostart=False)
    finally:
        node.destroy_node()


@pytest.mark.fault
def test_a_restarted_autopilot_gets_the_held_command_back_by_the_refresh(harness, autopilot, fault_row):
    # an autopilot that lost its outputs and reports nothing: the periodic refresh alone
    start_at(harness, autopilot, (0.2, 0.5, 0.9), command_timeout_s=30.0, refresh_s=0.5)
    expected = {ch: round(1000 + 1000 * u) for ch, u in zip(CHANNELS, (0.2, 0.5, 0.9))}
    autopilot.reboot()
    assert outputs_are(autopilot, SAFE)()
    t0 = time.monotonic()
    for _ in range(30):
        harness.command((0.2, 0.5, 0.9))   # the coordinator republishes the same command
        if outputs_are(autopilot, expected)():
            break
        time.sleep(0.1)
    assert outputs_are(autopilot, expected)(), autopilot.outputs()
    assert time.monotonic() - t0 < 2.0
    assert int(harness.fresh_diag()['resyncs']) == 0   # the refresh did it, not the read-back check
    fault_row('autopilot restarts between two heartbeat checks', 'the held command is sent again '
              'within refresh_s', True)
