"""The fuzz tier at the node level: the services and the topic other processes on the ROS domain
reach, sent hostile requests by hypothesis through real (in-process) nodes.

field_estimator's EstimateField, sim_tunnel's Sweep and Place (the motion stage's interface),
and fan_output's FanCommand topic driving the loopback autopilot. Every request must end in an
answer: a result, or a refusal whose message says what was wrong (and stays short); the node
must go on serving; and no pulse may ever leave fan_output outside its configured range. A few
examples each (WIND_SHAPER_FUZZ_NODE_EXAMPLES, default 12): seconds in CI."""
import math
import os
import shutil
import threading
import time

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from wind_shaper_msgs.msg import FanCommand  # noqa: E402
from wind_shaper_msgs.srv import EstimateField, Place, Sweep  # noqa: E402

from wind_shaper.core.config import default_config_dir  # noqa: E402
from wind_shaper.ros import names, qos  # noqa: E402

pytestmark = pytest.mark.ros
EXAMPLES = int(os.environ.get('WIND_SHAPER_FUZZ_NODE_EXAMPLES') or 12)
#: The longest answer a refusal may give [characters].
MAX_MESSAGE = 2000
ANSWER_S = 10.0   # every request is answered within this [s], or the test fails


def fuzz_settings(examples=EXAMPLES):
    return settings(max_examples=examples, deadline=None, database=None, derandomize=True,
                    suppress_health_check=list(HealthCheck))


def wait_for(predicate, timeout_s=ANSWER_S, period=0.005):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period)
    return bool(predicate())


class Spun:
    """Nodes on one executor in a background thread, and a client node among them."""

    def __init__(self, context, *nodes):
        self.context = context
        self.client = rclpy.create_node('fuzz_client', context=context)
        self.nodes = [*nodes, self.client]
        self.executor = SingleThreadedExecutor(context=context)
        for node in self.nodes:
            self.executor.add_node(node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self.stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def answer(self, client, request, timeout_s=ANSWER_S):
        assert client.wait_for_service(timeout_sec=ANSWER_S), f'{client.srv_name} not available'
        future = client.call_async(request)
        assert wait_for(future.done, timeout_s), f'{client.srv_name} did not answer {request}'
        return future.result()

    def close(self):
        self.stop.set()
        self.thread.join(timeout=5.0)
        self.executor.shutdown(timeout_sec=2.0)
        for node in self.nodes:
            node.destroy_node()


def clear(response):
    """A result, or a refusal that says why in a short message."""
    if response.success:
        return 'ok'
    assert response.message.strip(), 'a refusal without a reason'
    assert len(response.message) < MAX_MESSAGE, response.message[:300]
    return 'refused'


# -- building blocks ------------------------------------------------------------------------------------
HOSTILE_FLOATS = [math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, -0.0, 1e6, -1.0, 0.5]


def floats():
    return st.one_of(st.floats(), st.sampled_from(HOSTILE_FLOATS), st.floats(-1, 1))


def float_lists(max_size=60):
    return st.one_of(st.lists(floats(), max_size=max_size),
                     st.integers(0, 50_000).map(lambda n: [0.1] * n))


def names_of(real):
    return st.one_of(st.just(list(real)), st.permutations(list(real)),
                     st.lists(st.one_of(st.sampled_from(list(real)), st.text(max_size=200)),
                              max_size=80))


# -- field_estimator: EstimateField ---------------------------------------------------------------------
@pytest.fixture
def estimator(ros_context):
    from wind_shaper.nodes.field_estimator import FieldEstimatorNode
    node = FieldEstimatorNode(context=ros_context,
                              parameter_overrides=[Parameter('journal_dir', value='')])
    spun = Spun(ros_context, node)
    yield spun, node
    spun.close()


def test_estimate_field_requests_end_in_an_answer(estimator):
    spun, node = estimator
    fans = list(node._fan_names)
    begin = spun.client.create_client(Trigger, names.BEGIN_SWEEP)
    estimate = spun.client.create_client(EstimateField, names.ESTIMATE_FIELD)
    n_keys = len(node._key_points)
    outcomes = []

    from wind_shaper.app import Setup
    setup = Setup.load()
    sim = setup.make_sim(seed=0)
    U = np.where(setup.geometry.fans.enabled, 0.5, 0.0)
    sim.apply(U)
    sweep = sim.sweep(setup.shaping.samples_per_sweep)
    t0 = time.time()

    def collected():
        """begin_sweep, then a simulated sweep's samples as the topics would have brought them
        (in-process: the node's own buffers), so that a request's fields reach the estimate."""
        assert spun.answer(begin, Trigger.Request()).success
        for t, (x, y), f in zip(sweep.times, sweep.positions, sweep.forces):
            node._force.append(t0 + t, f)
            node._pose.append(t0 + t, x, y)

    @fuzz_settings()
    @given(st.data())
    def check(data):
        request = EstimateField.Request(
            iteration=data.draw(st.integers(-2**31, 2**31 - 1)),
            fan_names=data.draw(st.one_of(st.just(fans), names_of(fans))),
            pwm=data.draw(st.one_of(st.just([float(u) for u in U]), float_lists())),
            required=data.draw(st.one_of(st.just([]), st.lists(st.booleans(), max_size=400),
                                         st.integers(0, 3).map(lambda k: [True] * (n_keys + k)))),
            peek=data.draw(st.booleans()))
        kind = data.draw(st.sampled_from(['samples', 'begun', 'nothing']))
        if kind == 'samples':
            collected()
        elif kind == 'begun':
            assert spun.answer(begin, Trigger.Request()).success
        outcomes.append(clear(spun.answer(estimate, request)))

    check()
    print(f'EstimateField: {outcomes.count("ok")} results, {outcomes.count("refused")} refusals')
    assert outcomes.count('refused') >= 1   # a request with no sweep behind it is refused
    # the node serves on: a plain request over a sweep gets its estimate
    collected()
    assert spun.answer(estimate, EstimateField.Request(
        iteration=0, fan_names=fans, pwm=[float(u) for u in U])).success


# -- sim_tunnel: Sweep and Place ------------------------------------------------------------------------
@pytest.fixture
def tunnel(ros_context, tmp_path):
    from wind_shaper.nodes.sim_tunnel import SimTunnel
    config = tmp_path / 'config'
    shutil.copytree(default_config_dir(), config)
    sim = yaml.safe_load((config / 'sim.yaml').read_text())
    sim['sim']['noise'] = 'zero'
    (config / 'sim.yaml').write_text(yaml.safe_dump(sim))
    node = SimTunnel(context=ros_context, parameter_overrides=[
        Parameter('config_dir', value=str(config)), Parameter('mavlink_port', value=0),
        Parameter('netft_port', value=0)])
    spun = Spun(ros_context, node)
    yield spun, node
    spun.close()


def test_sweep_and_place_requests_end_in_an_answer(tunnel):
    spun, node = tunnel
    sweep = spun.client.create_client(Sweep, names.SWEEP)
    place = spun.client.create_client(Place, names.PLACE)
    outcomes = {'sweep': [], 'place': []}
    short = st.one_of(st.floats(0.05, 0.3), st.sampled_from([0.0, -1.0, math.nan, math.inf, 1e9,
                                                             1e308, 5e-324]))

    @fuzz_settings()
    @given(st.data())
    def check(data):
        if data.draw(st.booleans()):
            request = Sweep.Request(duration_s=data.draw(short),
                                    seed=data.draw(st.integers(0, 2**32 - 1)),
                                    region_x=data.draw(float_lists(20)),
                                    region_y=data.draw(float_lists(20)),
                                    region_reach=data.draw(floats()))
            t0 = time.monotonic()
            outcomes['sweep'].append(clear(spun.answer(sweep, request, timeout_s=ANSWER_S)))
            # a motion takes its duration plus the transit back; a refusal comes at once
            assert time.monotonic() - t0 < ANSWER_S
        else:
            # near points (a short transit) and hostile ones
            xy = st.one_of(st.floats(-0.05, 0.05), st.sampled_from(HOSTILE_FLOATS), st.floats())
            request = Place.Request(x=data.draw(xy), y=data.draw(xy))
            outcomes['place'].append(clear(spun.answer(place, request)))

    check()
    print({k: (v.count('ok'), v.count('refused')) for k, v in outcomes.items()})
    assert 'refused' in outcomes['sweep'] + outcomes['place']
    # the node serves on: a plain short sweep still runs
    assert spun.answer(sweep, Sweep.Request(duration_s=0.2)).success


# -- fan_output: the FanCommand topic --------------------------------------------------------------------
FANS = ['a', 'b', 'c']
CHANNELS = [3, 5, 1]
U_MIN, U_MAX = 0.1, 0.8


def test_fan_commands_never_drive_a_fan_out_of_range(ros_context):
    from wind_shaper.nodes.fan_output import FanOutputNode
    from wind_shaper.sim import SimAutopilot
    pulses = []
    with SimAutopilot(heartbeat_hz=20.0, servo_output_hz=20.0) as autopilot:
        autopilot.on_outputs = lambda out: pulses.append(dict(out))
        node = FanOutputNode(context=ros_context, parameter_overrides=[
            Parameter(k, value=v) for k, v in dict(
                fan_names=FANS, channels=CHANNELS, mavlink_url=autopilot.url, u_min=U_MIN,
                u_max=U_MAX, slew_rate_per_s=100.0, heartbeat_timeout_s=0.5,
                send_rate_hz=50.0).items()])
        spun = Spun(ros_context, node)
        try:
            pub = spun.client.create_publisher(FanCommand, names.FAN_COMMAND, qos.COMMAND)
            counts = node._counts   # in-process: what fan_output made of each message

            def handled():
                return counts['commands'] + counts['rejected']

            # the subscription matched: a first command is taken
            assert wait_for(lambda: (pub.publish(FanCommand(names=FANS, pwm=[0.3] * 3))
                                     or handled() > 0), 10.0)
            sent = [handled()]

            @fuzz_settings(EXAMPLES * 3)
            @given(st.data())
            def check(data):
                msg = FanCommand(names=data.draw(names_of(FANS)), pwm=data.draw(float_lists(10)))
                before = handled()
                pub.publish(msg)
                # every message is either taken (clipped into range) or refused and counted
                assert wait_for(lambda: handled() > before, 5.0), (list(msg.names), list(msg.pwm))

            check()
            time.sleep(0.3)   # the slew reaches its last target
            low, high = round(1000 + 1000 * U_MIN), round(1000 + 1000 * U_MAX)
            seen = [out[ch] for out in pulses for ch in CHANNELS]
            outside = sorted({us for us in seen if not (low <= us <= high or us == 1000)})
            assert not outside, f'pulses outside [{low}, {high}] us (or the safe 1000 us): {outside}'
            assert counts['exceptions'] == 0 if 'exceptions' in counts else True
            # the node serves on: a plain command is applied
            pub.publish(FanCommand(names=FANS, pwm=[0.5, 0.5, 0.5]))
            assert wait_for(lambda: all(autopilot.outputs()[ch] == 1500 for ch in CHANNELS), 5.0)
        finally:
            spun.close()
