"""sim_tunnel in-process: the rig's protocols on loopback (MAVLink, Net F/T RDT), mocap poses and
the sweep service, checked with the project's own clients (MavlinkFanLink, NetFtClient,
PlateRelay) against the plant's ground truth."""
import shutil
import threading
import time
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial import cKDTree

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from wind_shaper_msgs.srv import Sweep  # noqa: E402

from wind_shaper.core.area import SweepArea  # noqa: E402
from wind_shaper.core.config import default_config_dir  # noqa: E402
from wind_shaper.core.errors import ConfigError  # noqa: E402
from wind_shaper.estimation.frames import PlateRelay, RigidTransform  # noqa: E402
from wind_shaper.protocols.mavlink_fans import FanChannel, FanChannelMap  # noqa: E402
from wind_shaper.protocols.netft import NetFtCalibration  # noqa: E402
from wind_shaper.io import MavlinkFanLink, NetFtClient  # noqa: E402
from wind_shaper.nodes.sim_tunnel import SimTunnel, SimTunnelParams  # noqa: E402
from wind_shaper.ros import names, qos  # noqa: E402

from waiting import wait_for  # noqa: E402

pytestmark = pytest.mark.ros
CONFIG = Path(__file__).resolve().parents[2] / 'config' / 'sim_tunnel.yaml'
FANS = ['LM1', 'HM1', 'LM2', 'HM2', 'LM3', 'HM3', 'CM']
TUNNEL_FROM_MOCAP = [0.5, -0.25, 1.2, 0.0, 0.0, float(np.sin(0.3)), float(np.cos(0.3))]
OFFSET = [0.02, -0.01, -0.04]


@pytest.fixture
def quiet_config(tmp_path):
    """The shipped config folder with a noise-free simulator: measurements = ground truth."""
    out = tmp_path / 'config'
    shutil.copytree(default_config_dir(), out)
    sim = yaml.safe_load((out / 'sim.yaml').read_text())
    sim['sim']['noise'] = 'zero'
    (out / 'sim.yaml').write_text(yaml.safe_dump(sim))
    return out


class Harness:
    """The node on free loopback ports and a client node, spun on a background thread."""

    def __init__(self, context, config_dir, **overrides):
        params = dict(config_dir=str(config_dir), mavlink_port=0, netft_port=0,
                      tunnel_from_mocap=TUNNEL_FROM_MOCAP, plate_offset=OFFSET)
        params.update(overrides)
        self.node = SimTunnel(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        self.client = rclpy.create_node('sim_tunnel_test_client', context=context)
        self.poses, self.diagnostics = [], []
        self.client.create_subscription(PoseStamped, names.MOCAP_POSE, self.poses.append,
                                        qos.STREAM)
        self.client.create_subscription(DiagnosticArray, names.DIAGNOSTICS,
                                        self.diagnostics.append, 10)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.client)
        # spin in small steps until told to stop: shutting the executor down while spin() is
        # inside it races with rclpy's wait set (seen as thread exceptions at teardown)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self.stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def sweep(self, duration_s, timeout_s, **region):
        client = self.client.create_client(Sweep, names.SWEEP)
        try:
            assert client.wait_for_service(timeout_sec=3.0), 'sweep service not available'
            future = client.call_async(Sweep.Request(duration_s=float(duration_s), **region))
            assert wait_for(future.done, timeout_s), 'the sweep service did not answer in time'
            return future.result()
        finally:
            self.client.destroy_client(client)

    def close(self):
        self.stop.set()
        self.thread.join(timeout=5.0)
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        self.client.destroy_node()


@pytest.fixture
def harness(ros_context, quiet_config):
    made = []

    def make(**overrides):
        h = Harness(ros_context, quiet_config, **overrides)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


def test_yaml_lists_every_parameter_with_a_comment():
    doc = yaml.safe_load(CONFIG.read_text())['sim_tunnel']['ros__parameters']
    assert set(doc) == {f.name for f in fields(SimTunnelParams)}
    SimTunnelParams(**{k: tuple(v) if isinstance(v, list) else v for k, v in doc.items()})
    text = CONFIG.read_text()
    for name in doc:
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(f'{name}:'))
        assert '#' in line, f'{name} has no comment in {CONFIG.name}'


@pytest.mark.parametrize('node, keys', [
    ('fan_output', {'fan_names': 'fan_names', 'channels': 'channels', 'pwm_min_us': 'pwm_min_us',
                    'pwm_max_us': 'pwm_max_us', 'flavour': 'flavour'}),
    ('force_sensor', {'counts_per_force': 'counts_per_force',
                      'counts_per_torque': 'counts_per_torque', 'netft_port': 'sensor_port'}),
    ('mocap_relay', {'tunnel_from_mocap': 'tunnel_from_mocap', 'plate_offset': 'plate_offset',
                     'mocap_topic': 'input_topic'}),
])
def test_the_shipped_rig_settings_match_the_drivers(node, keys):
    """The drivers run unchanged against the simulated rig only if both sides agree."""
    other = CONFIG.parent / f'{node}.yaml'
    assert other.is_file(), f'config/{node}.yaml is missing'
    mine = yaml.safe_load(CONFIG.read_text())['sim_tunnel']['ros__parameters']
    theirs = yaml.safe_load(other.read_text())[node]['ros__parameters']
    for key, their_key in keys.items():
        assert mine[key] == theirs[their_key], f'{key} differs from {node}.yaml {their_key}'
    if node == 'fan_output':
        assert theirs['mavlink_url'] == f'udpout:127.0.0.1:{mine["mavlink_port"]}'
    if node == 'force_sensor':
        assert theirs['sensor_host'] == '127.0.0.1' and theirs['force_sign'] == 1
    if node == 'mocap_relay':   # the relay must not drop the sim's fastest motion as jumps
        assert mine['max_sweep_speed'] < theirs['max_speed_m_s']


@pytest.mark.fault
def test_the_simulated_rig_listens_on_loopback_only(harness, fault_row):
    h = harness()
    bound = {'MAVLink': h.node._autopilot.address, 'Net F/T': h.node._netft.address}
    fault_row('a packet for the simulated rig from another machine',
              'cannot arrive: its MAVLink and Net F/T sockets are bound to 127.0.0.1 '
              '(and `wind-shaper up` keeps ROS discovery on LOCALHOST)',
              all(host == '127.0.0.1' for host, _ in bound.values()))
    assert all(host == '127.0.0.1' for host, _ in bound.values()), bound


def test_mavlink_commands_drive_the_plant(harness):
    h = harness()
    cmap = FanChannelMap(FanChannel(n, ch) for n, ch in zip(FANS, range(1, 8)))
    link = MavlinkFanLink(f'udpout:127.0.0.1:{h.node.mavlink_port}', 'ardupilot_servo', cmap)
    try:
        assert link.wait_heartbeat(3.0), 'no heartbeat from the simulated autopilot'
        wanted = np.array([0.2, 0.3, 0.4, 0.5, 0.6, 0.25, 0.45])
        result = link.send(wanted.tolist(), wait_ack_s=2.0)
        assert result.accepted
        assert wait_for(lambda: np.allclose(h.node.live.pwm, wanted, atol=1e-3), 2.0), \
            f'plant pwm {h.node.live.pwm} != sent {wanted}'
        assert wait_for(lambda: h.node.live.field_current, 3.0)
        # the autopilot reports back what it applied, as the real one does
        assert wait_for(lambda: len(link.applied) == 7, 2.0)
        assert [link.applied[n] for n in FANS] == pytest.approx(wanted, abs=1e-3)
        # diagnostics (1 Hz) tell the applied PWMs and who is connected
        def latest():
            return {kv.key: kv.value for d in h.diagnostics[-1:] for kv in d.status[0].values}
        # one report that has both: the field is recomputed after the command lands
        assert wait_for(lambda: any('HM2=0.500' in v for v in latest().values())
                        and latest().get('force_field_current') == 'true', 6.0), latest()
        values = latest()
        assert values['mavlink_peer'] != 'None' and values['force_field_current'] == 'true'
    finally:
        link.close()


def test_netft_streams_the_plate_force_where_the_plate_is(harness):
    h = harness(rest_position=[0.1, -0.05])
    live = h.node.live
    pwm = np.array([0.5, 0.4, 0.5, 0.4, 0.5, 0.4, 0.3])
    live.apply(pwm)
    assert wait_for(lambda: live.field_current, 3.0)
    samples = []
    client = NetFtClient('127.0.0.1', h.node.netft_port, calibration=NetFtCalibration(1e6, 1e6),
                         on_sample=lambda s, stats: samples.append(s), local_host='127.0.0.1')
    try:
        client.start()
        assert wait_for(lambda: len(samples) >= 300, 6.0), f'only {len(samples)} RDT records'
        t0, n0 = time.monotonic(), len(samples)
        first = samples[n0 - 1].rdt_sequence
        time.sleep(1.0)
        # the sensor's own count of what it streamed (skipped records included), so a loaded
        # machine that delays this process does not read as a slow sensor
        rate = (samples[-1].rdt_sequence - first) / (time.monotonic() - t0)
        delivered = (len(samples) - n0) / max(samples[-1].rdt_sequence - first, 1)
    finally:
        client.close()
    true = live.tunnel.true_field(pwm, [(0.1, -0.05)])[0]
    fz = np.array([s.force[2] for s in samples])
    assert all(s.ok for s in samples)
    assert np.allclose(fz, true, atol=0.01 * true), f'Fz {fz.min():.3f}..{fz.max():.3f} != {true:.3f}'
    assert np.allclose([s.force[:2] for s in samples], 0.0)
    assert 800 < rate < 1200, f'RDT rate {rate:.0f} Hz, expected ~1000'
    assert delivered > 0.5, f'only {100 * delivered:.0f} % of the streamed records arrived'


def test_mocap_poses_give_the_plate_back_through_the_relay_transform(harness):
    h = harness(rest_position=[0.05, -0.3], plate_height_m=0.4)
    assert wait_for(lambda: len(h.poses) >= 100, 6.0), f'only {len(h.poses)} poses'
    stamps = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in h.poses[:100]])
    assert np.diff(stamps) == pytest.approx(0.01, abs=1e-6)   # capture times of 100 Hz frames
    relay = PlateRelay(RigidTransform.from_xyz_quat(TUNNEL_FROM_MOCAP), OFFSET)
    msg = h.poses[-1]
    assert msg.header.frame_id == 'mocap'
    stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    assert abs(stamp - time.time()) < 1.0          # capture time on the ROS (system) clock
    p, q = msg.pose.position, msg.pose.orientation
    assert (p.x, p.y, p.z) != pytest.approx((0.05, -0.3, 0.4), abs=0.05)   # really the mocap frame
    plate = relay.plate_pose((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))
    assert plate.translation == pytest.approx((0.05, -0.3, 0.4), abs=1e-9)


@pytest.mark.slow
def test_a_sweep_moves_the_plate_over_the_key_points_in_the_requested_time(harness):
    h = harness()
    relay = PlateRelay(RigidTransform.from_xyz_quat(TUNNEL_FROM_MOCAP), OFFSET)
    assert wait_for(lambda: len(h.poses) > 5, 3.0)
    start = len(h.poses)
    t0 = time.monotonic()
    response = h.sweep(3.0, timeout_s=6.0)
    took = time.monotonic() - t0
    assert response.success, response.message
    # the requested time at least, and answered when the tour ends, not at the 6 s timeout
    # (loose above: a loaded host overruns the tour's clock a little)
    assert 3.0 <= response.duration_s < 4.0 and took < 5.5
    time.sleep(0.1)   # the poses published at the very end are still on their way
    xy = []
    for msg in list(h.poses[start:]):
        p, q = msg.pose.position, msg.pose.orientation
        xy.append(relay.process(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
                                (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)))
    accepted = [r for r in xy if r.position is not None]
    refused = [(i, r) for i, r in enumerate(xy) if r.position is None]
    assert len(accepted) == len(xy) > 250, f'the relay refused poses {refused} (of {len(xy)})'
    pts = np.array([r.position[:2] for r in accepted])
    gap, _ = cKDTree(pts).query(h.node.live.geometry.key_points)
    # 5 cm when the machine is idle; poses lost on a busy machine leave 9 cm holes (the
    # coordinator sweeps again when the estimator refuses such a sweep)
    assert gap.max() < 0.11, f'a key point is {gap.max():.3f} m from every sample'
    assert np.allclose(pts[-1], (0.0, -0.34), atol=1e-6)   # back at rest
    assert h.node.sweeps_done == 1
    # a region sweep: the plate keeps to the region (after its transit from rest) and passes
    # every key point in it
    kp = h.node.live.geometry.key_points
    area = SweepArea(kp[(kp[:, 0] > 0.1) & (kp[:, 1] > 0.0)], 0.10)
    start = len(h.poses)
    response = h.sweep(2.0, timeout_s=5.0, region_x=area.centres[:, 0].tolist(),
                       region_y=area.centres[:, 1].tolist(), region_reach=area.reach)
    assert response.success, response.message
    time.sleep(0.1)
    results = []
    for msg in list(h.poses[start:]):
        p, q = msg.pose.position, msg.pose.orientation
        results.append(relay.process(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
                                     (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)))
    # where the plate goes is tested here, not the relay's gate: in a fresh clone's run on a
    # loaded machine the relay refused a pose here once (which verdict was not recorded); a few
    # refusals are let through, and more fail with their verdicts
    refused = [(i, r.verdict, r.speed) for i, r in enumerate(results) if r.position is None]
    assert len(refused) <= 2, f'the relay refused poses {refused} (of {len(results)})'
    pts = np.array([r.position[:2] for r in results if r.position is not None])
    assert np.mean(area.contains(pts)) > 0.6, np.mean(area.contains(pts))
    gap, _ = cKDTree(pts).query(area.centres)
    assert gap.max() < 0.08, f'a region key point is {gap.max():.3f} m from every sample'


def test_bad_sweep_requests_and_parameters_are_refused(harness, ros_context, quiet_config):
    h = harness()
    response = h.sweep(0.0, timeout_s=2.0)
    assert not response.success and 'duration_s' in response.message
    response = h.sweep(1e6, timeout_s=2.0)
    assert not response.success and 'max_sweep_duration_s' in response.message
    response = h.sweep(1.0, timeout_s=2.0, region_x=[0.1, 0.2], region_y=[0.0], region_reach=0.1)
    assert not response.success and '2 x but 1 y' in response.message, response.message
    response = h.sweep(1.0, timeout_s=2.0, region_x=[0.1], region_y=[0.0], region_reach=0.0)
    assert not response.success and 'reach > 0' in response.message, response.message
    assert h.node.sweeps_done == 0
    with pytest.raises(ConfigError, match='fan_names'):
        SimTunnel(context=ros_context, parameter_overrides=[
            Parameter('config_dir', value=str(quiet_config)),
            Parameter('fan_names', value=['LM1', 'XX9']), Parameter('channels', value=[1, 2])])
    with pytest.raises(ConfigError, match='channels'):
        SimTunnel(context=ros_context, parameter_overrides=[
            Parameter('config_dir', value=str(quiet_config)), Parameter('channels', value=[1, 2])])


def test_a_region_that_cannot_be_planned_is_refused_at_once(harness):
    """Found by the node-level fuzz tier: a region reach of 5e-324 m planned tours without end
    (the service never answered, then the node died of MemoryError); a region of thousands of
    points, or points far outside the tunnel, cost K x K distances or planned nonsense."""
    h = harness()
    for region, says in (
            (dict(region_x=[0.0], region_y=[0.0], region_reach=5e-324), 'reach > 0'),
            (dict(region_x=[0.0], region_y=[0.0], region_reach=float('nan')), 'reach > 0'),
            (dict(region_x=[1e308], region_y=[0.0], region_reach=0.1), 'inside the tunnel'),
            (dict(region_x=[0.0] * 3000, region_y=[0.0] * 3000, region_reach=0.1),
             'more than the 2000')):
        t0 = time.monotonic()
        response = h.sweep(0.2, timeout_s=5.0, **region)
        assert not response.success and says in response.message, response.message
        assert time.monotonic() - t0 < 2.0 and len(response.message) < 400
    assert h.node.sweeps_done == 0
    assert h.sweep(0.2, timeout_s=10.0, region_x=[0.1], region_y=[0.0], region_reach=0.1).success
