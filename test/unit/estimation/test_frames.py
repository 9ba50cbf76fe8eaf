"""Rigid transforms and the plate relay's gate, against hand-computed cases."""
import math

import numpy as np
import pytest

from wind_shaper.core.errors import ConfigError, FrameError
from wind_shaper.estimation.frames import (PlateRelay, RigidTransform, Verdict, quat_from_yaw,
                                     quat_multiply, quat_normalize, quat_rotate, quat_to_yaw)

S = math.sqrt(0.5)
YAW90 = (0.0, 0.0, S, S)          # +90 deg about z
ROLL90 = (S, 0.0, 0.0, S)         # +90 deg about x


def test_rotations_by_hand():
    assert np.allclose(quat_rotate(YAW90, [1, 0, 0]), [0, 1, 0])
    assert np.allclose(quat_rotate(YAW90, [0, 1, 0]), [-1, 0, 0])
    assert np.allclose(quat_rotate(ROLL90, [0, 1, 0]), [0, 0, 1])
    assert np.allclose(quat_rotate(ROLL90, [[0, 0, 1], [1, 0, 0]]), [[0, -1, 0], [1, 0, 0]])
    # rotate by ROLL90 first, then YAW90: y -> z -> z
    assert np.allclose(quat_rotate(quat_multiply(YAW90, ROLL90), [0, 1, 0]), [0, 0, 1])
    # and x -> x -> y
    assert np.allclose(quat_rotate(quat_multiply(YAW90, ROLL90), [1, 0, 0]), [0, 1, 0])


def test_transform_applies_rotation_then_translation():
    t = RigidTransform([1.0, 2.0, 3.0], YAW90)
    assert np.allclose(t.apply([1, 0, 0]), [1, 3, 3])
    assert np.allclose(t.apply([[0, 0, 0], [0, 2, 0]]), [[1, 2, 3], [-1, 2, 3]])
    assert np.allclose(t.matrix @ [0, 2, 0, 1], [-1, 2, 3, 1])


def test_compose_and_inverse_by_hand():
    a_from_b = RigidTransform([1, 0, 0], YAW90)
    b_from_c = RigidTransform([1, 0, 0])
    a_from_c = a_from_b @ b_from_c
    assert np.allclose(a_from_c.translation, [1, 1, 0])
    assert math.isclose(a_from_c.yaw, math.pi / 2)
    assert np.allclose(a_from_c.apply([1, 0, 0]), [1, 2, 0])
    assert np.allclose(a_from_c.apply([1, 0, 0]), a_from_b.apply(b_from_c.apply([1, 0, 0])))
    inv = a_from_b.inverse()
    assert np.allclose(inv.translation, [0, 1, 0])      # R^-1 (-t) = Rz(-90) (-1, 0, 0)
    assert (a_from_b @ inv).allclose(RigidTransform.identity())
    assert np.allclose(inv.apply(a_from_b.apply([0.3, -0.2, 0.7])), [0.3, -0.2, 0.7])


def test_matches_scipy_on_random_transforms(rng):
    Rotation = pytest.importorskip('scipy.spatial.transform').Rotation
    for _ in range(20):
        qa, qb = Rotation.random(2, random_state=rng.integers(1 << 30)).as_quat()
        ta, tb, p = rng.normal(size=(3, 3))
        a, b = RigidTransform(ta, qa), RigidTransform(tb, qb)
        expected = Rotation.from_quat(qa).apply(Rotation.from_quat(qb).apply(p) + tb) + ta
        assert np.allclose((a @ b).apply(p), expected)
        assert np.allclose(a.matrix[:3, :3], Rotation.from_quat(qa).as_matrix())
        assert math.isclose(a.yaw, Rotation.from_quat(qa).as_euler('ZYX')[0], abs_tol=1e-9)


def test_yaw():
    assert math.isclose(quat_to_yaw(YAW90), math.pi / 2)
    assert math.isclose(quat_to_yaw(ROLL90), 0.0, abs_tol=1e-12)
    assert math.isclose(quat_to_yaw((0, 0, 1, 0)), math.pi)      # 180 deg about z
    pitch20 = (0.0, math.sin(math.radians(10)), 0.0, math.cos(math.radians(10)))
    q = quat_multiply(quat_from_yaw(math.radians(30)), pitch20)  # yaw after pitch (z-y-x)
    assert math.isclose(quat_to_yaw(q), math.radians(30))
    assert math.isclose(quat_to_yaw(quat_from_yaw(-2.0)), -2.0)


def test_bad_quaternions_and_parameters_are_refused():
    for q in ((0, 0, 0, 0), (0, 0, 0, 2), (math.nan, 0, 0, 1), (0, 0, 1)):
        with pytest.raises(FrameError):
            quat_normalize(q)
    assert np.allclose(quat_normalize((0, 0, 0, 1.0005)), (0, 0, 0, 1))
    with pytest.raises(FrameError, match='translation'):
        RigidTransform([0, math.inf, 0])
    with pytest.raises(ConfigError, match='7 numbers'):
        RigidTransform.from_xyz_quat([0, 0, 0, 0, 0, 0])
    with pytest.raises(ConfigError, match='norm'):
        RigidTransform.from_xyz_quat([0, 0, 0, 0, 0, 0, 0])
    with pytest.raises(ConfigError, match='max_speed'):
        PlateRelay(RigidTransform(), max_speed_m_s=0.0)


@pytest.fixture
def relay():
    # tunnel = yaw 90 deg of the mocap frame, shifted; the plate centre 5 cm below the body origin
    return PlateRelay(RigidTransform.from_xyz_quat([0.1, -0.2, 0.0, *YAW90]),
                      plate_offset=(0.0, 0.0, -0.05), max_speed_m_s=3.0, max_radius_m=0.4)


def test_relay_transforms_the_plate_centre(relay):
    # body at (0.5, 0, 1) in mocap, level: centre (0.5, 0, 0.95) -> yaw 90: (0, 0.5, 0.95) + t
    r = relay.process(10.0, (0.5, 0.0, 1.0), (0, 0, 0, 1))
    assert r.verdict is Verdict.ACCEPTED
    assert np.allclose(r.position, [0.1, 0.3, 0.95])
    assert math.isclose(quat_to_yaw(r.orientation), math.pi / 2)
    # a body rolled 90 deg about x: the offset (0, 0, -0.05) points along +y of the mocap frame
    r = relay.process(10.1, (0.5, 0.0, 1.0), ROLL90)
    assert np.allclose(r.position, [0.1 - 0.05, 0.3, 1.0])
    assert r.speed == pytest.approx(math.hypot(0.05, 0.05) / 0.1)
    assert not r.outside


def test_relay_drops_nan_stale_and_jumps(relay):
    assert relay.process(1.00, (0.0, 0.0, 1.0), (0, 0, 0, 1)).verdict is Verdict.ACCEPTED
    assert relay.process(1.01, (math.nan, 0.0, 1.0), (0, 0, 0, 1)).verdict is Verdict.INVALID
    assert relay.process(1.01, (0.0, 0.0, 1.0), (0, 0, 0, 0)).verdict is Verdict.INVALID
    assert relay.process(1.00, (0.0, 0.0, 1.0), (0, 0, 0, 1)).verdict is Verdict.STALE
    assert relay.process(0.99, (0.0, 0.0, 1.0), (0, 0, 0, 1)).verdict is Verdict.STALE
    jump = relay.process(1.02, (0.1, 0.0, 1.0), (0, 0, 0, 1))     # 0.1 m in 0.02 s = 5 m/s
    assert jump.verdict is Verdict.JUMP and jump.speed == pytest.approx(5.0)
    assert jump.position is None
    ok = relay.process(1.03, (0.02, 0.0, 1.0), (0, 0, 0, 1))      # 0.02 m in 0.03 s vs last good
    assert ok.verdict is Verdict.ACCEPTED and ok.speed == pytest.approx(0.02 / 0.03)
    s = relay.stats
    assert (s.accepted, s.invalid, s.stale, s.jumps) == (2, 2, 2, 1)
    assert relay.last_time == 1.03


def test_relay_recovers_after_a_real_jump_and_flags_outside(relay):
    relay.process(0.0, (0.0, 0.0, 1.0), (0, 0, 0, 1))
    # the body reappears 0.5 m away and stays there: rejected until 0.5 m / dt <= 3 m/s
    verdicts = [relay.process(k * 0.01, (0.5, 0.0, 1.0), (0, 0, 0, 1)).verdict
                for k in range(1, 30)]
    first_ok = verdicts.index(Verdict.ACCEPTED) + 1
    assert first_ok == 17                     # 0.5 / 0.17 = 2.94 m/s; 0.5 / 0.16 = 3.1 m/s
    assert all(v is Verdict.ACCEPTED for v in verdicts[first_ok - 1:])
    # (0.5, 0, 1) in mocap is (0.1, 0.3) in the tunnel: inside 0.4 m; (1, 0, 1) -> (0.1, 0.8)
    r = relay.process(1.0, (1.0, 0.0, 1.0), (0, 0, 0, 1))
    assert r.verdict is Verdict.ACCEPTED and r.outside
    assert relay.stats.outside == 1
