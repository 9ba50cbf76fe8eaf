"""The ROS domains of the test lanes (tools/dev.sh test runs the tiers as several pytest
processes at once; test/conftest.py gives every test a domain of its own lane)."""


def lane_domain_id(base: int, lane: int, lanes: int, count: int) -> int:
    """The ``count``-th ROS_DOMAIN_ID of ``lane`` (0..lanes-1) in a run with base id ``base``:
    lane w takes base + w, base + w + lanes, ..., wrapped within the largest multiple of
    ``lanes`` that fits in 1..100, so it is never one another lane of the run has (wrapped at
    100 itself, three lanes met after 34 ids: a node test then got a graph's force stream)."""
    span = (100 // lanes) * lanes
    return (base + lane + lanes * count) % span + 1
