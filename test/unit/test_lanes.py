"""The test lanes' ROS domains (test/lanes.py): lanes that run at once never share one."""
import pytest
from lanes import lane_domain_id


@pytest.mark.parametrize('lanes', [1, 2, 3, 4, 5])
def test_lanes_running_at_once_never_share_a_domain(lanes):
    for base in range(1, 102):
        ids = [{lane_domain_id(base, lane, lanes, k) for k in range(150)} for lane in range(lanes)]
        assert all(1 <= d <= 100 for lane in ids for d in lane)
        for a in range(lanes):
            for b in range(a + 1, lanes):
                assert not ids[a] & ids[b], (base, a, b, sorted(ids[a] & ids[b])[:5])


def test_a_lane_uses_many_domains_before_it_wraps():
    # a domain is reused only after every other id of its lane: 33 ids with three lanes
    assert len({lane_domain_id(7, 1, 3, k) for k in range(33)}) == 33


def test_every_test_module_has_a_name_of_its_own():
    """The lanes run apart, but `WIND_SHAPER_TEST_LANES=1` and plain `pytest` collect every tier
    in one process, where pytest imports test modules by their file name (no packages here):
    two files of one name in different tiers stop that collection with an import mismatch."""
    from pathlib import Path
    tests = Path(__file__).resolve().parents[1]
    seen: dict[str, list[str]] = {}
    for path in tests.rglob('test_*.py'):
        seen.setdefault(path.name, []).append(str(path.relative_to(tests)))
    assert not {name: paths for name, paths in seen.items() if len(paths) > 1}
