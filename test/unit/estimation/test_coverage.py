"""estimation.coverage: the key points a moving plate has passed."""
import numpy as np
import pytest

from wind_shaper.estimation import Coverage, coverage_share


def grid(n=5, step=0.03):
    g = np.arange(n) * step
    return np.array([(x, y) for x in g for y in g])


def test_a_key_point_counts_once_a_position_comes_within_the_radius():
    kp = grid()
    c = Coverage(kp, 0.01)
    assert c.share == 0.0 and len(c.missed) == 25
    c.add((0.0, 0.005))          # within 1 cm of (0, 0) only
    assert c.passed.sum() == 1 and c.passed[0]
    c.add(kp[:10] + 0.009)        # 0.9 cm diagonally: 1.27 cm away, outside
    assert c.passed.sum() == 1
    c.add(kp[:10] + 0.005)        # 0.7 cm: inside
    assert c.share == pytest.approx(10 / 25)
    c.add([[np.nan, 0.0], [np.inf, np.inf]])  # lost mocap frames change nothing
    assert c.share == pytest.approx(10 / 25)
    c.reset()
    assert c.share == 0.0


def test_the_share_agrees_with_the_estimators_gap_rule():
    rng = np.random.default_rng(0)
    kp = grid(8)
    P = rng.uniform(-0.01, 0.22, (400, 2))
    d = np.min(np.linalg.norm(kp[:, None, :] - P[None, :, :], axis=2), axis=1)
    assert coverage_share(P, kp, 0.02) == pytest.approx(np.mean(d <= 0.02))


def test_a_radius_that_is_not_positive_is_refused():
    with pytest.raises(ValueError, match='radius'):
        Coverage(grid(), 0.0)
