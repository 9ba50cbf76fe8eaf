"""Bags across processes: `wind-shaper record` keeps a live sweep whole through a SIGINT, and a
recorded sweep replayed into the field_estimator node gives the field the core computes offline
from the same bag."""
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from wind_shaper.bag import topics as bt  # noqa: E402
from wind_shaper_msgs.srv import EstimateField  # noqa: E402

from wind_shaper.bag import BagReader, read_sweep_records, write_sweep_bag  # noqa: E402
from wind_shaper.ros import names  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

HERE = Path(__file__).parent
BIN = Path(sys.executable).parent        # console scripts of the environment
SWEEP_S = 2.0                            # the live sweep [s]
DISCOVERY_S = 20.0                       # bound on discovery between processes
LIFETIME_S = 60.0                        # children end by themselves after this


def wait_for_exit(process, timeout_s):
    try:
        return process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return None


def output(process):
    return process.log_path.read_text()


@pytest.mark.timeout(90)
def test_a_live_sweep_recorded_by_another_process_survives_sigint_whole(ros_process, tmp_path):
    bag_path = tmp_path / 'live'
    topics = [bt.FORCE, bt.PLATE_POSE, bt.STATUS, bt.FAN_COMMAND]
    recorder = ros_process(BIN / 'wind-shaper', 'record', '--out', bag_path, '--topics', *topics)
    publisher = ros_process(HERE / 'sweep_publisher.py', SWEEP_S, LIFETIME_S)
    code = wait_for_exit(publisher, DISCOVERY_S + SWEEP_S + 15)
    assert code == 0, f'publisher exit {code}:\n{output(publisher)}\nrecorder:\n{output(recorder)}'
    time.sleep(0.3)  # the last messages' way to the recorder
    recorder.send_signal(signal.SIGINT)  # as Ctrl-C
    code = wait_for_exit(recorder, 10)
    assert code == 0, f'recorder exit {code} after SIGINT:\n{output(recorder)}'
    assert 'recorded' in output(recorder)

    n_force = int(SWEEP_S * 1000)
    with BagReader(bag_path) as bag:
        counts = {name: info.count for name, info in bag.topics.items()}
        forces = [(t, m) for _, t, m in bag.decoded([bt.FORCE])]
    assert counts == {bt.FORCE: n_force, bt.PLATE_POSE: n_force // 10, bt.STATUS: 3,
                      bt.FAN_COMMAND: 1}, output(recorder)
    # nothing lost or reordered at 1 kHz between processes; each message received after its
    # sample time, and soon after it was published (a busy publisher may fall behind its 1 ms
    # schedule; that is its delay, not the recorder's)
    assert [int(m.header.frame_id) for _, m in forces] == list(range(n_force))
    after_sample = np.array([t * 1e-9 - (m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec)
                             for t, m in forces])
    latency = np.array([t * 1e-9 - m.wrench.torque.x for t, m in forces])
    assert np.all(after_sample > 0) and np.all(latency > 0) and np.median(latency) < 0.05

    (record,) = read_sweep_records(bag_path)
    assert (record.iteration, record.source, record.complete) == (0, 'status', True)
    assert record.fan_names == ('fan_00', 'fan_01', 'fan_02')
    np.testing.assert_array_equal(record.sweep.pwm, [0.2, 0.4, 0.6])
    j = np.arange(n_force // 10)
    assert len(record.sweep) >= len(j) - 1  # the last pose may miss force after its stamp
    published = np.column_stack([0.001 * j, -0.002 * j])
    np.testing.assert_allclose(record.sweep.positions, published[:len(record.sweep)])
    np.testing.assert_allclose(record.sweep.forces, 2.5)
    assert record.sweep.times[-1] == pytest.approx(0.01 * (len(record.sweep) - 1), abs=0.05)


# -- the recorded sweep replayed into the field estimator ------------------------------------------

WAIT_S = 20.0
FORCE_RATE_HZ = 200.0                    # force rate of the replayed bag [Hz]


def spin_until(node, condition, timeout_s=WAIT_S):
    from rclpy.executors import SingleThreadedExecutor
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    deadline = time.monotonic() + timeout_s
    try:
        while not condition() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.remove_node(node)
        executor.shutdown()
    return condition()


def call(node, client, request, timeout_s=WAIT_S):
    future = client.call_async(request)
    assert spin_until(node, future.done, timeout_s), \
        f'{client.srv_name} did not answer within {timeout_s} s'
    return future.result()


def buffered(diagnostics):
    """(force, pose) samples the field estimator reports buffered in its last diagnostics."""
    for array in reversed(diagnostics):
        for status in array.status:
            if status.name.endswith(names.FIELD_ESTIMATOR):
                values = {kv.key: kv.value for kv in status.values}
                return int(values.get('force_samples', -1)), int(values.get('pose_samples', -1))
    return None


@pytest.mark.timeout(120)
def test_a_replayed_sweep_bag_gives_the_field_estimate_the_core_computes_offline(
        ros_context, ros_process, tmp_path):
    """begin_sweep, replay the bag's force and plate pose, estimate: the node's pairs and field
    equal core FieldEstimator on read_sweeps' output of the same bag."""
    pytest.importorskip('wind_shaper.nodes.field_estimator')
    from wind_shaper.app import Setup
    from wind_shaper.core.config import default_config_dir
    from wind_shaper.bag.player import Player
    from wind_shaper.sim import SimulatedTunnel

    # the shipped config with a looser coverage check, so a 3 s sweep is enough
    config = tmp_path / 'config'
    shutil.copytree(default_config_dir(), config)
    shaping = yaml.safe_load((config / 'shaping.yaml').read_text())
    shaping['shaping']['estimator']['max_gap'] = 0.2
    (config / 'shaping.yaml').write_text(yaml.safe_dump(shaping))
    setup = Setup.load(config)
    fan_names = list(setup.geometry.fans.names)
    sim = SimulatedTunnel(setup.geometry, seed=2, sample_rate_hz=100.0)
    sim.apply(np.full(len(fan_names), 0.5))
    # force at 200 Hz, not the rig's 1 kHz: the test is about equal results, and on 2 shared
    # cores under load the node's executor dropped 25-50 % of a 500 Hz or 1 kHz stream
    bag_path = write_sweep_bag(tmp_path / 'sweep', [sim.sweep(300)], fan_names=fan_names,
                               iterations=[3], idle_streams=False, force_rate_hz=FORCE_RATE_HZ)
    (record,) = read_sweep_records(bag_path)
    offline = setup.shaping.make_estimator(setup.load_model()).estimate(record.sweep,
                                                                        setup.geometry.key_points)

    # a bag holds the per-sample wrenches: the estimator reads them instead of the blocks
    estimator = ros_process(BIN / 'field_estimator', '--ros-args', '-p', f'config_dir:={config}',
                            '-p', "force_block_topic:=''")
    node = rclpy.create_node('bag_replay_coordinator', context=ros_context)
    player = None
    try:
        diagnostics = []
        node.create_subscription(DiagnosticArray, bt.DIAGNOSTICS, diagnostics.append, 10)
        begin = node.create_client(Trigger, names.BEGIN_SWEEP)
        estimate = node.create_client(EstimateField, names.ESTIMATE_FIELD)
        assert begin.wait_for_service(timeout_sec=WAIT_S) and estimate.wait_for_service(
            timeout_sec=WAIT_S), f'field_estimator offers no services:\n{output(estimator)}'
        player = Player(bag_path, topics=[bt.FORCE, bt.PLATE_POSE], context=ros_context,
                        wait_for_subscribers_s=WAIT_S)
        assert call(node, begin, Trigger.Request()).success
        stats = player.play()  # real time
        assert stats.published[bt.FORCE] == record.n_force
        # the node takes what DDS delivered at its own pace: wait until it has everything
        want = (record.n_force, record.n_pose)
        assert spin_until(node, lambda: buffered(diagnostics) == want), \
            f'field_estimator buffered {buffered(diagnostics)} (force, pose) of {want}'
        request = EstimateField.Request(iteration=3, fan_names=fan_names,
                                        pwm=[float(u) for u in record.sweep.pwm])
        response = call(node, estimate, request)
    finally:
        if player is not None:
            player.destroy()
        node.destroy_node()
    assert response.success, f'{response.message}\n{output(estimator)}'

    samples = response.samples
    assert len(samples.x) == len(record.sweep), 'the node paired a different number of samples'
    np.testing.assert_array_equal(np.column_stack([samples.x, samples.y]), record.sweep.positions)
    np.testing.assert_allclose(samples.force, record.sweep.forces, rtol=0, atol=1e-12)
    field = response.estimate
    assert field.iteration == 3 and field.n_used == offline.n_used
    np.testing.assert_allclose(np.column_stack([field.x, field.y]), setup.geometry.key_points)
    np.testing.assert_allclose(field.mean, offline.mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(field.std, offline.std, rtol=0, atol=1e-9)
