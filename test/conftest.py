"""Shared fixtures: the paper rig's geometry, seeded randomness, and real ROS 2 processes.

Every ROS participant of a test uses the run's ROS_DOMAIN_ID (tools/dev.sh test sets one per
run) and LOCALHOST discovery, so parallel runs on one machine do not see each other.
"""
import itertools
import os
from pathlib import Path
import signal
import subprocess
import sys

import numpy as np
import pytest

from wind_shaper.core.geometry import TunnelGeometry

from lanes import lane_domain_id


@pytest.fixture
def rig():
    return TunnelGeometry.paper_rig()


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def _stop(process, grace_s=5.0):
    """Stop a child: SIGINT (rclpy's clean shutdown path), then SIGKILL after grace_s [s]."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=grace_s)


_domain_counter = itertools.count()
_BASE_DOMAIN = int(os.environ.get('ROS_DOMAIN_ID') or os.getpid() % 100 + 1)
#: tools/dev.sh test runs the tiers as several pytest processes at once (WIND_SHAPER_TEST_LANES,
#: 3); each takes domains no other lane has (``lanes.lane_domain_id``).
_LANES = max(int(os.environ.get('WIND_SHAPER_TEST_LANES') or 1), 1)
_LANE = int(os.environ.get('WIND_SHAPER_TEST_LANE') or 0) % _LANES


def next_domain_id() -> str:
    """A ROS_DOMAIN_ID no other test of this run has had (the run's base id plus a counter,
    within 1..100, interleaved over the lanes): whatever a test leaves behind cannot reach the
    next."""
    return str(lane_domain_id(_BASE_DOMAIN, _LANE, _LANES, next(_domain_counter)))


if _LANES > 1:   # what runs with the plain environment stays in this lane's domains too
    os.environ['ROS_DOMAIN_ID'] = next_domain_id()


@pytest.fixture(scope='session')
def new_domain_id():
    """``new_domain_id() -> str``: next_domain_id for fixtures wider than one test."""
    return next_domain_id


@pytest.fixture
def ros_env(monkeypatch):
    """Set and return the ROS environment of this test and of the processes it starts.

    Each test gets its own ROS_DOMAIN_ID (the run's base id plus a counter, within 1..100), so
    nothing an earlier test left in DDS (participants, in-process streams still winding down)
    reaches it."""
    monkeypatch.setenv('ROS_DOMAIN_ID', next_domain_id())
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.delenv('ROS_LOCALHOST_ONLY', raising=False)  # deprecated; conflicts with the above
    return dict(os.environ)


@pytest.fixture
def ros_context(ros_env):
    """An initialised rclpy context of its own, shut down after the test."""
    rclpy = pytest.importorskip('rclpy')
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    try:
        yield context
    finally:
        context.try_shutdown()


@pytest.fixture
def ros_process(ros_env, tmp_path):
    """Start a Python script as a separate ROS process: ``start(script, *args) -> Popen``.

    The child gets the test's ROS environment, no stdin and the test's tmp_path as working
    directory (so relative defaults such as runs/ land there); its output goes to
    ``process.log_path``. Every child still running at teardown is stopped.
    """
    started = []

    def start(script, *args):
        script = Path(script)
        log_path = tmp_path / f'{script.stem}-{len(started)}.log'
        with open(log_path, 'wb') as log:
            process = subprocess.Popen(
                [sys.executable, str(script), *map(str, args)],
                env=ros_env, cwd=tmp_path, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True)  # a Ctrl-C in the terminal goes to pytest only
        process.log_path = log_path
        started.append(process)
        return process

    yield start
    for process in started:
        _stop(process)


# -- the fault table (tools/fault_table.py) ----------------------------------------------------
_FAULT_ROWS: list = []
_FAILED: set = set()


@pytest.fixture
def fault_row(request):
    """``fault_row(fault, outcome, survived, samples_lost=None)``: one row of the fault table.
    A row of a test that fails counts as not survived. Rows are written to
    $WIND_SHAPER_FAULT_TABLE (JSON lines) at the end of the run when that is set."""
    def record(fault: str, outcome: str, survived: bool, samples_lost: int | None = None) -> None:
        _FAULT_ROWS.append({'fault': fault, 'outcome': outcome, 'survived': bool(survived),
                            'samples_lost': None if samples_lost is None else int(samples_lost),
                            'test': request.node.nodeid})
    return record


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    report = (yield).get_result()
    if report.failed:
        _FAILED.add(item.nodeid)


def pytest_sessionfinish(session, exitstatus):
    path = os.environ.get('WIND_SHAPER_FAULT_TABLE')
    if path and _FAULT_ROWS:
        import json
        with open(path, 'a', encoding='utf-8') as fh:
            for row in _FAULT_ROWS:
                row = dict(row, survived=row['survived'] and row['test'] not in _FAILED)
                fh.write(json.dumps(row) + '\n')
