"""The test lanes' ROS domains (test/lanes.py): lanes that run at once never share one."""
import pytest
from lanes import lane_domain_id


@pytest.mark.parametrize('lanes', [1, 2, 3, 4])
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
