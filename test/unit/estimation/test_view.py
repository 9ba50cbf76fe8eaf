"""What the live view shows (estimation/view.py): the field's points, the fans, the sweep trail."""
import numpy as np
import pytest

from wind_shaper.core.geometry import FanArray
from wind_shaper.estimation.view import POINT_FIELDS, SweepTrail, fan_views, field_points


def test_field_points_carry_force_std_target_and_residual():
    kp = np.array([[0.0, 0.0], [0.1, -0.2]])
    rows = field_points(kp, [2.0, 3.0], [0.1, 0.2], [2.5, 2.5])
    assert rows.dtype == np.float32 and rows.shape == (2, len(POINT_FIELDS))
    np.testing.assert_allclose(rows[1], [0.1, -0.2, 0.0, 3.0, 0.2, 2.5, 0.5], atol=1e-6)
    assert np.isnan(field_points(kp, [2.0, 3.0], [0.1, 0.2])[:, 5:]).all()   # no target
    with pytest.raises(ValueError, match='2 key points but 3'):
        field_points(kp, [1.0, 2.0, 3.0], [0.1, 0.1, 0.1])


def test_fans_are_drawn_with_their_command_spin_and_a_size_from_their_spacing():
    fans = FanArray.paper_rig(0.25, disabled=['CM'])
    views = fan_views(fans, np.linspace(0.0, 1.2, 7))
    assert [v.name for v in views] == list(fans.names)
    assert views[-1].command == 1.0 and views[-1].label() == 'CM off'
    assert {v.spin for v in views} == {-1, 1}
    assert all(0.02 < v.radius < 0.1 for v in views)
    assert views[0].label() == f'{fans.names[0]} 0 % {"CCW" if views[0].spin > 0 else "CW"}'


def test_a_long_sweep_trail_keeps_its_extent_at_a_coarser_step():
    trail = SweepTrail(max_points=100)
    for i in range(1000):
        trail.add(i * 1e-3, 0.0)
    trail.add(float('nan'), 0.0)
    pts = trail.points
    assert 50 <= len(pts) <= 100 and pts[0, 0] == 0.0 and pts[-1, 0] > 0.9
    trail.clear()
    assert len(trail.points) == 0
