"""read_sweeps rebuilds the sweeps write_sweep_bag wrote: as the field estimator would pair them."""
import warnings

import numpy as np
import pytest

from wind_shaper.bag import BagReader, BagWriter, read_sweep_records, read_sweeps, write_sweep_bag
from wind_shaper.bag.types import typestore
from wind_shaper.core.errors import SweepError
from wind_shaper.estimation.field import FieldEstimator
from wind_shaper.estimation.frames import RigidTransform, quat_from_yaw
from wind_shaper.core.geometry import TunnelGeometry
from wind_shaper.bag import topics as bt


def assert_same_sweep(got, want):
    assert len(got) == len(want)
    np.testing.assert_array_equal(got.positions, want.positions)
    np.testing.assert_allclose(got.forces, want.forces, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.times, want.times - want.times[0], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(got.pwm, want.pwm)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_read_sweeps_recovers_every_sweep_and_skips_the_plate_at_rest(tmp_path, sim_sweeps, storage):
    path = write_sweep_bag(tmp_path / 'bag', sim_sweeps, iterations=[4, 5], storage=storage)
    records = read_sweep_records(path)
    assert [r.iteration for r in records] == [4, 5]
    assert all(r.complete and r.source == 'status' for r in records)
    for record, want in zip(records, sim_sweeps):
        assert_same_sweep(record.sweep, want)
        assert record.fan_names == tuple(f'fan_{i:02d}' for i in range(len(want.pwm)))
        assert record.n_pose == len(want) and record.n_force >= 10 * len(want)
    # the streams ran on while the plate rested: more force and pose in the bag than in sweeps
    with BagReader(path) as bag:
        topics = bag.topics
    assert topics[bt.FORCE].count > sum(r.n_force for r in records) + 1000
    assert topics[bt.PLATE_POSE].count > sum(len(s) for s in sim_sweeps) + 100
    assert topics[bt.FAN_APPLIED].count == 2 and topics[bt.STATUS].count > 10


def test_without_status_the_sweeps_are_cut_at_command_changes(tmp_path, sim_sweeps):
    path = write_sweep_bag(tmp_path / 'bag', sim_sweeps, with_status=False, idle_streams=False)
    records = read_sweep_records(path)
    assert [r.source for r in records] == ['commands', 'commands'] and records[0].iteration == -1
    for record, want in zip(records, sim_sweeps):
        assert_same_sweep(record.sweep, want)


def test_without_status_or_commands_the_whole_bag_is_one_sweep(tmp_path, sim_sweeps):
    path = write_sweep_bag(tmp_path / 'bag', sim_sweeps[:1], with_status=False, with_commands=False,
                           idle_streams=False)
    (record,) = read_sweep_records(path)
    assert record.source == 'whole' and record.sweep.pwm.shape == (0,)
    np.testing.assert_array_equal(record.sweep.positions, sim_sweeps[0].positions)


def test_forced_segmentation_modes(tmp_path, sim_sweeps):
    path = write_sweep_bag(tmp_path / 'bag', sim_sweeps, with_status=False)
    with pytest.raises(Exception, match='no /wind_shaper/iteration/status messages'):
        read_sweeps(path, segment_by='status')
    (whole,) = read_sweeps(path, segment_by='whole')
    assert len(whole) > sum(len(s) for s in sim_sweeps)  # the rests are in it too


def test_the_mocap_pose_is_written_in_the_mocap_frame(tmp_path, sim_sweeps):
    tunnel_from_mocap = RigidTransform([0.5, -0.2, 1.1], quat_from_yaw(0.3))
    path = write_sweep_bag(tmp_path / 'bag', sim_sweeps[:1], tunnel_from_mocap=tunnel_from_mocap,
                           idle_streams=False)
    with BagReader(path) as bag:
        poses = {topic: [] for topic in (bt.PLATE_POSE, bt.MOCAP_POSE)}
        for topic, _, msg in bag.decoded(list(poses)):
            p = msg.pose.position
            poses[topic].append((p.x, p.y, p.z))
    back = tunnel_from_mocap.apply(np.array(poses[bt.MOCAP_POSE]))
    np.testing.assert_allclose(back, poses[bt.PLATE_POSE], atol=1e-12)
    assert not np.allclose(poses[bt.MOCAP_POSE], poses[bt.PLATE_POSE])
    # and a bag read from the mocap topic pairs mocap-frame positions
    (raw,) = read_sweeps(path, pose_topic=bt.MOCAP_POSE)
    np.testing.assert_allclose(raw.positions, np.array(poses[bt.MOCAP_POSE])[:, :2])


def test_a_field_estimate_is_written_and_the_offline_estimate_matches_it(tmp_path, sim_sweeps):
    geometry = TunnelGeometry.paper_rig()
    estimator = FieldEstimator(min_samples=50, max_gap=1.0)
    estimate = estimator.estimate(sim_sweeps[0], geometry.key_points)
    path = write_sweep_bag(tmp_path / 'bag', sim_sweeps[:1], estimates=[estimate])
    with BagReader(path) as bag:
        (_, _, msg), = list(bag.decoded([bt.FIELD]))
    again = estimator.estimate(read_sweeps(path)[0], geometry.key_points)
    # the estimator fits its noise model to the sample times, which the bag keeps to the
    # nanosecond: the optimizer turns that into differences of micronewtons
    np.testing.assert_allclose(again.mean, msg.mean, atol=1e-5)
    np.testing.assert_allclose(again.std, msg.std, atol=1e-5)
    assert msg.n_samples == len(sim_sweeps[0]) and msg.iteration == 0


def test_a_sweep_whose_streams_cannot_be_paired_is_skipped_with_a_warning(tmp_path, sim_sweeps):
    """The coordinator reported 'sweeping' but the mocap sent nothing: skipped, or strict error."""
    T = typestore().types
    path = tmp_path / 'bag'
    with BagWriter(path) as bag:
        for topic in (bt.FORCE, bt.PLATE_POSE, bt.STATUS):
            bag.add_topic(topic)
        def header(t_ns):
            return T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](
                sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id='')
        def status(t_ns, k, state):
            return T['wind_shaper_msgs/msg/IterationStatus'](
                header=header(t_ns), iteration=k, state=state, progress=0.0, samples=0,
                coverage=float('nan'), max_std=float('nan'), message='',
                target='', fan_names=[], pwm=np.zeros(0), rmse=0.0, run_folder='')
        zero = T['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)
        bag.write(bt.STATUS, 0, status(0, 0, 'sweeping'))
        for j in range(1, 300):
            t = j * 1_000_000
            bag.write(bt.FORCE, t, T['geometry_msgs/msg/WrenchStamped'](
                header=header(t), wrench=T['geometry_msgs/msg/Wrench'](
                    force=T['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=1.0), torque=zero)))
        bag.write(bt.STATUS, 300_000_000, status(300_000_000, 0, 'estimating'))
        bag.write(bt.STATUS, 400_000_000, status(400_000_000, 1, 'sweeping'))
        for j in range(41, 60):
            t = j * 10_000_000
            bag.write(bt.FORCE, t, T['geometry_msgs/msg/WrenchStamped'](
                header=header(t), wrench=T['geometry_msgs/msg/Wrench'](
                    force=T['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=2.0), torque=zero)))
            bag.write(bt.PLATE_POSE, t, T['geometry_msgs/msg/PoseStamped'](
                header=header(t), pose=T['geometry_msgs/msg/Pose'](
                    position=T['geometry_msgs/msg/Point'](x=0.01 * j, y=0.0, z=0.0),
                    orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0))))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        records = read_sweep_records(path)
    assert [r.iteration for r in records] == [1] and not records[0].complete
    np.testing.assert_allclose(records[0].sweep.forces, 2.0)
    assert any('skipped iteration 0' in str(w.message) and 'no finite pose' in str(w.message)
               for w in caught)
    with pytest.warns(UserWarning, match='skipped iteration 0'):
        assert read_sweep_records(path, include_incomplete=False) == []
    with pytest.raises(SweepError, match='iteration 0: no finite pose'):
        read_sweeps(path, strict=True)
