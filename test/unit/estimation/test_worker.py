"""The field estimate in a worker process (``estimation.worker``): the same answer as in the
node's own process, refusals that come back as outcomes, and a worker that dies or hangs is
replaced, with the estimate it was computing failed with the reason."""
import os

import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.core.errors import WindShaperError
from wind_shaper.estimation.worker import EstimateWorker, StreamSnapshot, align_and_estimate


@pytest.fixture(scope='module')
def sweep_streams():
    """A simulated sweep as the field_estimator holds it: force at 10 x the pose rate."""
    setup = Setup.load()
    sim = setup.make_sim(seed=3)
    U = np.full(setup.geometry.fans.n_fans, 0.4)
    sim.apply(U)
    sweep = sim.sweep(500)
    t = sweep.times
    force_t = (t[:, None] + np.arange(10) * 0.002).ravel()
    streams = StreamSnapshot(force_t, np.repeat(sweep.forces, 10), t, sweep.positions[:, 0],
                             sweep.positions[:, 1], U, 0.0)
    return setup.shaping.make_estimator(), setup.geometry.key_points, streams


@pytest.fixture(scope='module')
def worker():
    w = EstimateWorker(timeout_s=60.0)
    w.start()
    yield w
    w.close()


def test_the_worker_gives_the_estimate_the_node_process_gives(sweep_streams, worker):
    estimator, kp, streams = sweep_streams
    here = align_and_estimate(estimator, kp, streams)
    there = worker.run(estimator, kp, streams)
    assert here.error is None and there.error is None
    assert len(there.sweep) == len(here.sweep)
    np.testing.assert_allclose(there.estimate.mean, here.estimate.mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(there.estimate.std, here.estimate.std, rtol=1e-9, atol=1e-12)
    # the GP comes back too: a robot's field query and the next estimate's reuse need it
    f, s = there.estimate.at(kp[:3], radius=1.0)
    np.testing.assert_allclose(f, here.estimate.mean[:3], rtol=1e-9)
    again = worker.run(estimator, kp, streams, reuse=there.estimate)
    np.testing.assert_allclose(again.estimate.mean, there.estimate.mean, rtol=1e-6)


def test_a_refused_sweep_comes_back_as_an_outcome_with_its_pairs(sweep_streams, worker):
    estimator, kp, streams = sweep_streams
    half = len(streams.pose_t) // 3   # the plate's first third: most key points never passed
    cut = StreamSnapshot(streams.force_t[:10 * half], streams.force[:10 * half], streams.pose_t[:half],
                         streams.pose_x[:half], streams.pose_y[:half], streams.pwm, 0.0)
    out = worker.run(estimator, kp, cut)
    assert out.estimate is None and out.sweep is not None
    assert 'missed' in str(out.error)
    # a peek estimates the field so far and reports the coverage apart
    peek = worker.run(estimator, kp, cut, peek=True)
    assert peek.error is None and peek.estimate is not None and 'missed' in str(peek.check)
    # streams that cannot be paired: no sweep at all
    empty = StreamSnapshot(np.array([]), np.array([]), streams.pose_t[:5], streams.pose_x[:5],
                           streams.pose_y[:5], streams.pwm, 0.0)
    none = worker.run(estimator, kp, empty)
    assert none.sweep is None and none.estimate is None and isinstance(none.error, WindShaperError)


def test_a_worker_that_dies_or_hangs_is_replaced_and_the_next_estimate_works(sweep_streams):
    estimator, kp, streams = sweep_streams
    w = EstimateWorker(timeout_s=60.0)
    try:
        w.start()
        assert w.run(estimator, kp, streams).error is None
        # the child dies while computing (out of memory, say): that estimate fails with the reason
        with pytest.raises(WindShaperError, match='died'):
            w._call(os._exit, 3)
        assert w.run(estimator, kp, streams).error is None and w.started == 2
        # killed while idle, between sweeps: the next estimate gets a new worker and is answered
        for proc in list(w._pool._processes.values()):
            proc.kill()
            proc.join(10)
        assert w.run(estimator, kp, streams).error is None and w.started == 3
        w.timeout_s = 1e-3                               # an estimate that takes too long
        with pytest.raises(WindShaperError, match='longer than'):
            w.run(estimator, kp, streams)
        w.timeout_s = 60.0
        assert w.run(estimator, kp, streams).error is None and w.started == 4
    finally:
        w.close()


def test_a_node_killed_outright_leaves_no_worker_behind(tmp_path):
    """The supervisor SIGKILLs a hung node: its worker process must not outlive it."""
    import signal
    import subprocess
    import sys
    import time
    script = tmp_path / 'node.py'
    script.write_text(
        'import sys, time\n'
        'from wind_shaper.estimation.worker import EstimateWorker\n'
        'if __name__ == "__main__":\n'
        '    w = EstimateWorker()\n'
        '    w.start()\n'
        '    w._call(time.sleep, 0)\n'
        '    print(*w._pool._processes, flush=True)\n'
        '    time.sleep(60)\n')
    node = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    worker_pid = None
    try:
        worker_pid = int(node.stdout.readline().split()[0])
        assert os.path.exists(f'/proc/{worker_pid}')
        node.send_signal(signal.SIGKILL)
        node.wait(10)
        deadline = time.monotonic() + 10
        while os.path.exists(f'/proc/{worker_pid}') and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not os.path.exists(f'/proc/{worker_pid}'), 'the worker outlived its node'
    finally:
        node.kill()
        node.wait(10)
        if worker_pid is not None and os.path.exists(f'/proc/{worker_pid}'):
            os.kill(worker_pid, signal.SIGKILL)   # leave nothing running, also when it failed
