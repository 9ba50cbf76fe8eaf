"""coordination.held and storage.held: the held-plate batch's points, the stillness check, and
the batch folder that resumes."""
import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.coordination.held import Stillness, held_points
from wind_shaper.core.errors import RunFolderError
from wind_shaper.model import CalibrationPlan
from wind_shaper.storage import RECORDED, SKIPPED, HeldBatch


@pytest.fixture(scope='module')
def geometry():
    return Setup.load().geometry


def test_the_paper_batch_has_231_points_of_which_those_past_the_sweep_disc_are_left_out(geometry):
    points, outside = held_points(geometry, CalibrationPlan())
    assert len(points) + outside == 7 * (17 + 16)
    assert all(np.hypot(p.x, p.y) <= geometry.sweep_radius + 1e-9 for p in points)
    assert len({p.label for p in points}) == len(points)
    first = points[0]
    assert first.label == 'LM1 0 % over the hub' and sum(first.pwm) == 0.0
    on = [p for p in points if 'HM2 50 %' in p.label]
    assert on and all(np.count_nonzero(p.pwm) == 1 for p in on)


def test_a_plate_counts_as_held_only_near_the_point_and_still():
    s = Stillness()
    assert 'no plate pose' in s.verdict(0.1, 0.0, 0.01, 1.0)
    for k in range(50):           # carried towards the point
        s.add(0.02 * k, 0.1 * k / 50, 0.0)
    assert 'from the point' in s.verdict(0.1, 0.0, 0.01, 1.0)
    for k in range(50, 150):       # held there, 2 s, with 1 mm of jitter
        s.add(0.02 * k, 0.1 + 0.001 * np.sin(k), 0.0)
    assert s.verdict(0.1, 0.0, 0.01, 1.0) == ''
    s.clear()
    for k in range(100):           # within tolerance but drifting 8 mm per second
        s.add(0.02 * k, 0.096 + 0.004 * np.sin(0.2 * k), 0.0)
    assert 'moves' in s.verdict(0.1, 0.0, 0.01, 1.0)


def test_a_batch_resumes_skips_and_takes_the_last_line_of_a_redone_point(tmp_path, geometry):
    points, _ = held_points(geometry, CalibrationPlan(levels=(0.0, 0.5), offsets=(0.1,)))
    rows = [dict(label=p.label, pwm=p.pwm, x=p.x, y=p.y) for p in points]
    batch = HeldBatch.open(tmp_path, 'b', geometry.fans.names, rows)
    batch.append(0, RECORDED, force_mean=0.1, force_std=0.01, n=20, x_mean=points[0].x, y_mean=points[0].y)
    batch.append(1, SKIPPED)
    batch.append(0, RECORDED, force_mean=0.2, force_std=0.01, n=20, x_mean=points[0].x, y_mean=points[0].y)
    with open(batch.folder / 'record.jsonl', 'a') as fh:
        fh.write('{"label": "cut by a cra')          # a crash in the middle of a line
    again = HeldBatch.open(tmp_path, 'b', geometry.fans.names, rows)
    assert again.pending() == list(range(2, len(points)))
    again.append(2, SKIPPED)      # the line after the cut one is whole
    assert again.pending() == list(range(3, len(points)))
    m = again.measurements()
    assert len(m.forces) == 1 and m.forces[0] == 0.2
    with pytest.raises(RunFolderError, match='other points'):
        HeldBatch.open(tmp_path, 'b', geometry.fans.names, rows[:-1])
