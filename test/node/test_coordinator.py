"""coordinator in-process against fakes backed by the simulated tunnel.

The fake rig echoes fan commands to /fans/applied through a SimulatedTunnel (so the plant runs
at what was commanded), answers the sweep service, and (unless the real field_estimator node is
used) answers begin_sweep / estimate with the core FieldEstimator on a simulator sweep.
"""
import math
import threading
import time

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from wind_shaper_msgs.msg import (ExperimentStatus, FanCommand, ForceBlock, IterationStatus,  # noqa: E402
                                  SweepSamples)
from wind_shaper_msgs.srv import Collect, EstimateField, RunIteration, SetModel, Sweep  # noqa: E402

from wind_shaper.app import Setup  # noqa: E402
from wind_shaper.cli.main import main as cli  # noqa: E402
from wind_shaper.control import ShapingConfig  # noqa: E402
from wind_shaper.model.modelfile import save_model  # noqa: E402
from wind_shaper.storage.runstore import RunStore  # noqa: E402
from wind_shaper.nodes.coordinator import CoordinatorNode  # noqa: E402
from wind_shaper.nodes.field_estimator import FieldEstimatorNode  # noqa: E402
from wind_shaper.ros import names, qos  # noqa: E402
from wind_shaper.ros.convert import (estimate_to_msg, fan_command, pwm_from_command,  # noqa: E402
                                     seconds_to_stamp, sweep_to_msg)
from wind_shaper.sim.paths import TourPath  # noqa: E402

pytestmark = pytest.mark.ros

WAIT_S = 15.0  # bound on every wait: a broken node fails the test in seconds


def wait_until(predicate, timeout=WAIT_S, period=0.01):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period)
    return bool(predicate())


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


class FakeRig(Node):
    """Fan driver + sweep + (optionally) field estimator, backed by a SimulatedTunnel.

    echo: publish every FanCommand back on /fans/applied (as the plant applied it), from a node
    of its own (``fans``) so the read-back goes on while a sweep call blocks this one;
    estimator: serve begin_sweep / estimate from simulator sweeps; stream: during a sweep,
    publish force and plate pose from the simulator for the real field_estimator node.
    During a sweep, ``fault`` makes the read-back go 'silent' or report fan 0 'off' (stopped)."""

    def __init__(self, context, setup, *, echo=True, estimator=True, stream=False, seed=0):
        super().__init__('fake_rig', context=context)
        self.setup = setup
        self.sim = setup.make_sim(seed=seed)
        self.fans = list(setup.geometry.fans.names)
        self.echo, self.stream = echo, stream
        self.sink = None  # the field_estimator node fed by stream sweeps
        self.commands = []
        self.sweeps = 0
        self.refuse_estimates = 0
        self.peeks = 0
        self.sweep_requests, self.estimate_requests = [], []
        self.stop = threading.Event()
        self.sweeping = False
        self.fault = None
        self.estimator = setup.shaping.make_estimator(setup.load_model())
        self.fans_node = rclpy.create_node('fake_rig_fans', context=context)
        self.applied_pub = self.fans_node.create_publisher(FanCommand, names.FAN_APPLIED,
                                                           qos.LATCHED)
        self.fans_node.create_subscription(FanCommand, names.FAN_COMMAND, self._on_fans_command,
                                           qos.COMMAND)
        self.create_service(Sweep, names.SWEEP, self._handle_sweep)
        if estimator:
            self.create_service(Trigger, names.BEGIN_SWEEP, self._handle_begin_sweep)
            self.create_service(EstimateField, names.ESTIMATE_FIELD, self._handle_estimate)
        if stream:
            self.force_pub = self.create_publisher(ForceBlock, names.FORCE_BLOCK, qos.STREAM)
            self.pose_pub = self.create_publisher(PoseStamped, names.PLATE_POSE, qos.STREAM)

    def _on_fans_command(self, msg):
        pwm = pwm_from_command(msg, self.fans)
        self.commands.append(pwm)
        applied = self.sim.apply(pwm)
        if self.sweeping and self.fault == 'silent':
            return
        if self.sweeping and self.fault == 'off':
            applied = np.array(applied, dtype=float)
            applied[0] = 0.0
        if self.echo:
            self.applied_pub.publish(fan_command(self.fans, applied))

    def _handle_sweep(self, request, response):
        self.sweeps += 1
        self.sweep_requests.append(request)
        self.sweeping = True
        try:
            return self._sweep(request, response)
        finally:
            self.sweeping = False

    def _sweep(self, request, response):
        if self.stream:
            self._stream_sweep(request.duration_s)
        else:
            end = time.monotonic() + request.duration_s
            while time.monotonic() < end and not self.stop.is_set():
                time.sleep(0.01)
        response.success, response.duration_s = True, request.duration_s
        return response

    def _stream_sweep(self, duration_s, n_poses=300, per_pose=4):
        """A whole-disc tour: n_poses plate poses and per_pose force samples each, stamped on
        one clock. Published in chunks, each once ``self.sink`` (the field_estimator node) has
        buffered the last: KEEP_LAST queues drop what a starved subscriber has not taken, and
        this fake is about the service sequence, not DDS throughput."""
        rng = np.random.default_rng(self.sweeps)
        dt = 0.01 / per_pose
        n = n_poses * per_pose
        xy = TourPath(speed=4.0)(n, dt, self.sim.geometry.sweep_radius, rng)
        force = self.sim.true_field(self.sim.pwm, xy) + rng.normal(0, 0.03, n)
        t0 = time.time()
        sent = [0, 0]
        block = ForceBlock()
        for i in range(n):
            t = t0 + i * dt
            block.stamp.append(t)
            block.force_z.append(float(force[i]))
            if i % per_pose == per_pose - 1:   # the force in blocks, as force_sensor sends it
                self.force_pub.publish(block)
                sent[0] += len(block.stamp)
                block = ForceBlock()
            if i % per_pose == 1:
                pose = PoseStamped()
                pose.header.stamp = seconds_to_stamp(t + dt / 2)
                pose.pose.position.x, pose.pose.position.y = map(float, xy[i])
                pose.pose.orientation.w = 1.0
                self.pose_pub.publish(pose)
                sent[1] += 1
            if i % 40 == 39:
                assert wait_until(lambda: len(self.sink._pose) == sent[1]
                                  and len(self.sink._force) == sent[0],
                                  timeout=5.0), f'field_estimator buffered {len(self.sink._force)} ' \
                    f'force / {len(self.sink._pose)} pose samples of {sent}'
        time.sleep(max(0.0, duration_s - (time.time() - t0)))

    def _handle_begin_sweep(self, request, response):
        response.success = True
        return response

    def _handle_estimate(self, request, response):
        if request.peek:   # how far the sweep is: this fake never says 'enough'
            self.peeks += 1
            response.success = False
            response.message = 'not enough yet'
            return response
        self.estimate_requests.append(request)
        sweep = self.sim.sweep(self.setup.shaping.samples_per_sweep)
        if self.refuse_estimates > 0:  # as the real estimator does when a sweep left gaps:
            self.refuse_estimates -= 1  # refused, with the pairs it could make
            response.success = False
            response.message = 'the sweep missed 7 of 317 key points'
            response.samples = sweep_to_msg(sweep, request.iteration, request.fan_names)
            return response
        est = self.estimator.estimate(sweep, self.setup.geometry.key_points,
                                      required=list(request.required) or None)
        response.estimate = estimate_to_msg(est, request.iteration, request.fan_names, request.pwm,
                                            len(sweep))
        response.samples = sweep_to_msg(sweep, request.iteration, request.fan_names)
        response.success = True
        return response

    def rmse_true(self, pwm, target_spec='parabolic'):
        kp = self.setup.geometry.key_points
        target = self.setup.make_target(target_spec).values(kp)
        return float(np.sqrt(np.mean((self.sim.true_field(pwm, kp) - target) ** 2)))


def spin(node, context):
    """Spin ``node`` on its own executor in a thread until ``thread.stop`` is set (stopping the
    loop before shutting the executor down avoids rclpy's shutdown-while-spinning race)."""
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stop = threading.Event()

    def loop():
        while not stop.is_set() and context.ok():
            executor.spin_once(timeout_sec=0.05)

    thread = threading.Thread(target=loop, daemon=True)
    thread.stop = stop
    thread.start()
    return executor, thread


class Graph:
    """A coordinator, a fake rig and a client node, each spun by its own executor."""

    DEFAULTS = dict(sweep_duration_s=0.2, settle_s=0.0, apply_timeout_s=3.0, service_timeout_s=5.0,
                    iteration_timeout_s=30.0)

    def __init__(self, context, setup, run_root, **rig):
        self.context, self.setup, self.run_root = context, setup, run_root
        self.spun = []
        self.rig = self._spin(FakeRig(context, setup, **rig))
        self._spin(self.rig.fans_node)
        self.client = rclpy.create_node('coordinator_test_client', context=context)
        self.statuses = []
        self.client.create_subscription(IterationStatus, names.STATUS, self.statuses.append,
                                        qos.LATCHED)
        self.diagnostics = []
        self.client.create_subscription(DiagnosticArray, names.DIAGNOSTICS,
                                        lambda m: self.diagnostics.extend(m.status), 10)
        self.run = self.client.create_client(RunIteration, names.RUN_ITERATION)
        self.cancel = self.client.create_client(Trigger, names.CANCEL_ITERATION)
        self.set_model = self.client.create_client(SetModel, names.SET_MODEL)
        self.collect = self.client.create_client(Collect, names.COLLECT)
        self.experiment_statuses, self.experiment_sweeps = [], []
        self.client.create_subscription(ExperimentStatus, names.EXPERIMENT_STATUS,
                                        self.experiment_statuses.append, qos.LATCHED)
        self.client.create_subscription(SweepSamples, names.EXPERIMENT_SWEEPS,
                                        self.experiment_sweeps.append, qos.COMMAND)
        self._spin(self.client)
        self.coordinator = None

    def _spin(self, node):
        executor, thread = spin(node, self.context)
        self.spun.append((node, executor, thread))
        return node

    def _unspin(self, node):
        for entry in list(self.spun):
            if entry[0] is node:
                _, executor, thread = entry
                thread.stop.set()
                thread.join(timeout=WAIT_S)
                executor.shutdown(timeout_sec=WAIT_S)
                node.destroy_node()
                self.spun.remove(entry)

    def start_coordinator(self, **params):
        values = {**self.DEFAULTS, 'run_root': str(self.run_root), 'run_name': 'test', **params}
        overrides = [Parameter(k, value=v) for k, v in values.items()]
        self.coordinator = self._spin(CoordinatorNode(context=self.context,
                                                      parameter_overrides=overrides))
        assert self.run.wait_for_service(timeout_sec=WAIT_S)
        return self.coordinator

    def stop_coordinator(self):
        self._unspin(self.coordinator)
        self.coordinator = None

    def add_node(self, node):
        return self._spin(node)

    def call_async(self, client, request):
        assert client.wait_for_service(timeout_sec=WAIT_S)
        return client.call_async(request)

    def call(self, client, request, timeout=WAIT_S):
        future = self.call_async(client, request)
        assert wait_until(future.done, timeout), f'{client.srv_name} did not answer in {timeout} s'
        return future.result()

    def iterate(self, **fields):
        return self.call(self.run, RunIteration.Request(**fields), timeout=40.0)

    def status(self):
        return self.statuses[-1] if self.statuses else None

    def store(self):
        return RunStore.open(self.run_root, 'test')

    def close(self):
        self.rig.stop.set()
        for node, _, _ in reversed(list(self.spun)):
            self._unspin(node)


@pytest.fixture
def graph(ros_context, setup, tmp_path):
    g = Graph(ros_context, setup, tmp_path)
    yield g
    g.close()


def test_a_new_run_starts_at_the_prior_optimum_and_checks_the_first_sweep(graph):
    from wind_shaper.coordination import start_at_prior_optimum
    graph.start_coordinator()
    warm = start_at_prior_optimum(graph.setup, graph.setup.load_model(), 'parabolic')
    r = graph.iterate()
    assert r.success, r.message
    np.testing.assert_allclose(r.pwm_before, warm.U, atol=1e-9)
    # the warm start already sits near what the fans can do: the true error at iteration 0 is
    # within 25 % of the prior's own prediction of it, far below the fixed start's
    truth0 = graph.rig.rmse_true(r.pwm_before)
    assert truth0 < 0.5 * graph.rig.rmse_true(np.full(7, 0.5)), truth0
    record = graph.store().load_record(0)
    assert record['info']['warm_start']['check']['mismatch'] is False
    assert record['info']['plate_s'] > 0 and record['info']['settle_s'] >= 0


def test_iterations_through_the_service_lower_the_error(graph, fixed_start_config):
    graph.start_coordinator(config_dir=fixed_start_config)
    u0 = np.full(7, 0.5)
    results = [graph.iterate() for _ in range(4)]
    for k, r in enumerate(results):
        assert r.success, r.message
        assert r.iteration == k and list(r.fan_names) == list(graph.rig.fans)
        assert r.run_folder.endswith(f'k{k:03d}')
        assert np.all(np.asarray(r.pwm_after) >= 0) and np.all(np.asarray(r.pwm_after) <= 0.65)
        assert r.rmse_predicted_after < r.rmse_before  # the prior expects its step to help
        assert 0 < r.max_std < 1.0
    np.testing.assert_array_equal(results[0].pwm_before, u0)
    for a, b in zip(results, results[1:]):
        np.testing.assert_array_equal(b.pwm_before, a.pwm_after)
    rmse = [r.rmse_before for r in results]
    assert rmse[-1] < 0.75 * rmse[0], rmse
    # the plant ran at the commands, and its true error fell too
    truth = [graph.rig.rmse_true(r.pwm_before) for r in results]
    assert truth[-1] < 0.75 * truth[0], truth
    # the fans now hold U_4, republished for the watchdog
    n = len(graph.rig.commands)
    assert wait_until(lambda: len(graph.rig.commands) >= n + 2, timeout=3.0)
    np.testing.assert_array_equal(graph.rig.commands[-1], results[-1].pwm_after)
    # latched status and the run folder
    assert wait_until(lambda: graph.status() is not None
                      and graph.status().state == IterationStatus.STATE_DONE)
    st = graph.status()
    assert st.iteration == 3 and st.progress == pytest.approx(1.0) and st.target == 'parabolic'
    assert st.rmse == pytest.approx(rmse[-1]) and st.samples == 1000
    np.testing.assert_array_equal(st.pwm, results[-1].pwm_after)
    history = graph.store().load_history()
    assert [h.k for h in history] == [0, 1, 2, 3]
    assert [math.sqrt(h.error) for h in history] == pytest.approx(rmse, rel=1e-9)
    assert {s.state for s in graph.statuses} >= {'commanding', 'sweeping', 'estimating',
                                                 'updating', 'done'}
    assert wait_until(lambda: any(d.name == 'wind_shaper/coordinator' and d.message.startswith('done')
                                  for d in graph.diagnostics), timeout=3.0)


def test_a_refused_sweep_is_swept_again_up_to_max_sweeps(graph):
    graph.start_coordinator(max_sweeps=3)
    graph.rig.refuse_estimates = 2
    r = graph.iterate()
    assert r.success, r.message
    assert graph.rig.sweeps == 3 and r.iteration == 0
    graph.rig.refuse_estimates = 3
    r = graph.iterate()
    assert not r.success
    assert 'after 3 sweep(s)' in r.message and 'missed 7 of 317 key points' in r.message
    assert graph.rig.sweeps == 6
    assert graph.store().last_completed() == 0  # the failed iteration left the run as it was


@pytest.mark.fault
def test_second_call_is_refused_and_cancel_keeps_the_commands(graph, fault_row):
    graph.start_coordinator(sweep_duration_s=5.0)
    first = graph.iterate()
    assert first.success, first.message
    running = graph.call_async(graph.run, RunIteration.Request())
    assert wait_until(lambda: graph.status().state == IterationStatus.STATE_SWEEPING)
    t0 = time.monotonic()
    second = graph.iterate(target='uniform:2.0')
    assert not second.success and 'an iteration is running' in second.message
    assert time.monotonic() - t0 < 2.0  # refused at once, not queued
    assert graph.coordinator._run.target_spec == 'parabolic'
    # progress moves during the sweep, at 2 Hz
    n = len(graph.statuses)
    assert wait_until(lambda: len(graph.statuses) >= n + 2, timeout=3.0)
    assert 0.1 < graph.status().progress < 0.8
    cancelled = graph.call(graph.cancel, Trigger.Request())
    assert cancelled.success and 'cancelling iteration 1' in cancelled.message
    assert wait_until(running.done, timeout=3.0), 'cancel did not end the sweep wait'
    r = running.result()
    assert not r.success and 'cancelled' in r.message and r.iteration == 1
    np.testing.assert_array_equal(r.pwm_after, first.pwm_after)
    assert wait_until(lambda: graph.status().state == IterationStatus.STATE_CANCELLED)
    assert graph.store().last_completed() == 0  # the run did not advance
    assert graph.coordinator._run.k == 1
    np.testing.assert_array_equal(graph.rig.commands[-1], first.pwm_after)
    nothing = graph.call(graph.cancel, Trigger.Request())
    assert not nothing.success and 'no iteration or experiment is running' in nothing.message
    fault_row('a second run_iteration call while one runs',
              'refused, never interleaved; cancel keeps the last completed commands', True)


@pytest.mark.fault
def test_a_bad_target_is_refused_and_nothing_changes(graph, fault_row):
    graph.start_coordinator()
    r = graph.iterate(target='gaussian@NOPE')
    assert not r.success and 'NOPE' in r.message and 'nothing changed' in r.message
    assert graph.store().state().target == 'parabolic' and graph.store().last_completed() == -1
    assert graph.rig.commands == []  # nothing was commanded
    r = graph.iterate(target='uniform:40')   # far beyond the fans, per the prior
    assert not r.success and 'cannot reach' in r.message and 'nothing changed' in r.message
    assert graph.store().state().target == 'parabolic' and graph.rig.commands == []
    r = graph.iterate(step_gain=-1.0, target='uniform:2.0')
    assert r.success, r.message
    assert graph.store().state().target == 'uniform:2.0'
    assert graph.status().target == 'uniform:2.0'
    assert graph.store().load_record(0)['target'] == 'uniform:2.0'
    fault_row('a target that does not parse, names an unknown fan, or is out of reach',
              'refused with the reason; target, run and fans unchanged', True)


def edited_config(tmp_path, name, replacements):
    """The shipped config copied to tmp_path/name with shaping.yaml's texts replaced."""
    import shutil
    from wind_shaper.core.config import default_config_dir
    folder = tmp_path / name
    shutil.copytree(default_config_dir(), folder)
    shaping = folder / 'shaping.yaml'
    text = shaping.read_text()
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new, 1)
    shaping.write_text(text)
    return str(folder)


@pytest.fixture
def paper_config(tmp_path):
    """The shipped config with the paper's protocol: Algorithm 1 as the update rule (its step is
    gain / (k + 1)), from every fan at 0.5."""
    return edited_config(tmp_path, 'paper_config', [('method: adaptive', 'method: paper'),
                                                    ('u0: warm', 'u0: 0.5')])


@pytest.fixture
def fixed_start_config(tmp_path):
    """The shipped config starting every fan at 0.5 instead of the prior's optimum."""
    return edited_config(tmp_path, 'fixed_start', [('u0: warm', 'u0: 0.5')])


def test_with_region_sweeps_on_the_sweep_and_the_estimate_are_asked_for_the_region(graph, tmp_path):
    """shaping.sweep.region.enabled: after the first iteration the sweep service is asked for
    the region the step changed (its key points and reach) and the estimator for those key
    points only; the run records the region and the fused estimate."""
    config = edited_config(tmp_path, 'region', [('enabled: false', 'enabled: true')])
    graph.start_coordinator(config_dir=config, sweep_duration_s=1.0, sweep_min_s=0.2)
    # a region is swept once a step's predicted change is small enough to carry the rest
    # over (the first steps from the warm start move the field by 0.3-1.5 N RMS)
    for _ in range(6):
        r = graph.iterate(target='gaussian@LM1')
        assert r.success, r.message
        if any(len(q.region_x) for q in graph.rig.sweep_requests):
            break
    sweeps, estimates = graph.rig.sweep_requests, graph.rig.estimate_requests
    n_keys = len(graph.setup.geometry.key_points)
    assert len(sweeps[0].region_x) == 0 and len(estimates[0].required) == 0
    regional = [i for i, q in enumerate(sweeps) if len(q.region_x)]
    assert regional, 'no iteration swept a region'
    for i in regional:
        flags = np.asarray(estimates[i].required, dtype=bool)
        assert len(flags) == n_keys and 0 < flags.sum() < n_keys
        kp = graph.setup.geometry.key_points[flags]
        np.testing.assert_allclose(np.column_stack([sweeps[i].region_x, sweeps[i].region_y]), kp)
        assert sweeps[i].region_reach > 0 and sweeps[i].duration_s <= 1.0
    history = graph.store().load_history()
    assert [i for i, h in enumerate(history) if h.info.get('region')] == regional
    assert any('sweeping the region within' in s.message for s in graph.statuses)


def test_step_gain_override_scales_the_step(graph, paper_config):
    graph.start_coordinator(config_dir=paper_config)
    r = graph.iterate(step_gain=0.2)
    assert r.success, r.message
    assert graph.store().load_record(0)['step_size'] == pytest.approx(0.2)


def test_set_model_swaps_the_prior_and_refuses_a_broken_one(graph, setup, tmp_path):
    node = graph.start_coordinator()
    old = repr(node._run.model)
    model = setup.load_model()
    jets = model.k1.clone(sigma=0.2)
    path = save_model(tmp_path / 'model.yaml', jets + model.k2)
    r = graph.call(graph.set_model, SetModel.Request(model_yaml=path.read_text()))
    assert r.success, r.message
    assert repr(node._run.model) != old and 'sigma=0.2' in repr(node._run.model)
    assert 'sigma=0.2' in r.message and 'WARNING' not in r.message
    # a model whose commissioning found two fans swapped is taken, with a warning that says so
    doc = yaml.safe_load(path.read_text())
    doc['wiring_check'] = {'checked': True, 'swapped': ['HM1', 'LM3']}
    r = graph.call(graph.set_model, SetModel.Request(model_yaml=yaml.safe_dump(doc)))
    assert r.success and 'WARNING' in r.message and 'HM1 and LM3' in r.message, r.message
    for request, reason in [
            (SetModel.Request(model_yaml='wind_shaper_model: 1\nmodel: {kind: nope}\n'), 'nope'),
            (SetModel.Request(model_yaml='[not a mapping'), 'model_yaml'),
            (SetModel.Request(path=str(tmp_path / 'missing.yaml')), 'missing.yaml'),
            (SetModel.Request(), 'model_yaml text or as a path')]:
        r = graph.call(graph.set_model, request)
        assert not r.success and reason in r.message, r.message
        assert 'sigma=0.2' in repr(node._run.model)  # the good one stays
    r = graph.call(graph.set_model, SetModel.Request(path=str(setup.model_path)))
    assert r.success and repr(node._run.model) == old
    # the prior set at run time is kept with the run and used again after a restart; restarted
    # with another target, the run keeps its own and says so: a warning beside the information
    # on the prior, both logged at start (rclpy refuses two severities from one logging line)
    graph.stop_coordinator()
    node = graph.start_coordinator(target='uniform:3.0')
    assert repr(node._run.model) == old
    assert {level for level, _ in node._run.notes} == {'info', 'warning'}


def test_a_restart_resumes_at_the_next_iteration_with_the_same_commands(graph):
    graph.start_coordinator()
    results = [graph.iterate() for _ in range(2)]
    assert all(r.success for r in results)
    graph.stop_coordinator()
    n = len(graph.rig.commands)
    node = graph.start_coordinator(target='uniform:3.0')  # a new run's target: ignored here
    assert node._run.k == 2 and node._run.target_spec == 'parabolic'
    assert wait_until(lambda: len(graph.rig.commands) > n)  # published at start
    np.testing.assert_array_equal(graph.rig.commands[-1], results[-1].pwm_after)
    assert wait_until(lambda: graph.status() is not None and graph.status().iteration == 1
                      and graph.status().state == IterationStatus.STATE_IDLE)
    assert graph.status().rmse == pytest.approx(results[-1].rmse_before)
    r = graph.iterate()
    assert r.success and r.iteration == 2
    np.testing.assert_array_equal(r.pwm_before, results[-1].pwm_after)
    assert [h.k for h in graph.store().load_history()] == [0, 1, 2]


def test_update_rules_see_the_runs_history_across_restarts(graph, monkeypatch):
    seen = []
    make_rule = ShapingConfig.make_rule

    def recording(self, **overrides):
        rule = make_rule(self, **overrides)

        class Recording:
            bounds = rule.bounds

            def step(self, inp):
                seen.append(inp)
                return rule.step(inp)

        return Recording()

    monkeypatch.setattr(ShapingConfig, 'make_rule', recording)
    graph.start_coordinator()
    first = [graph.iterate() for _ in range(2)]
    graph.stop_coordinator()
    graph.start_coordinator()
    assert graph.iterate().success
    assert [len(inp.history) for inp in seen] == [0, 1, 2]
    for past, r in zip(seen[2].history, first):  # the history reloaded from the run folder
        np.testing.assert_array_equal(past.U, r.pwm_before)
    np.testing.assert_allclose(seen[2].history[1].mean, seen[1].target - seen[1].delta, atol=1e-12)
    assert seen[2].model is not None and seen[2].key_points.shape == (317, 2)


@pytest.mark.parametrize('fault, words', [('off', 'reported LM1 at 0.000 instead of 0.520'),
                                          ('silent', 'did not report their outputs')])
def test_a_sweep_during_which_the_fans_leave_their_commands_is_discarded(graph, fault, words):
    graph.start_coordinator(sweep_duration_s=3.0)
    graph.rig.fault = fault
    r = graph.iterate()
    assert not r.success and 'sweep discarded' in r.message and words in r.message, r.message
    assert graph.store().last_completed() == -1           # the run stays where it was
    assert graph.status().state == IterationStatus.STATE_FAILED
    graph.rig.fault = None
    r = graph.iterate()
    assert r.success and r.iteration == 0, r.message


def test_operator_sweep_waits_the_sweep_duration(graph):
    graph.start_coordinator(sweep_service='', sweep_duration_s=0.5)
    t0 = time.monotonic()
    r = graph.iterate()
    assert r.success, r.message
    assert time.monotonic() - t0 >= 0.5 and graph.rig.sweeps == 0


def test_fans_that_never_report_fail_the_iteration_with_the_cause(ros_context, setup, tmp_path):
    g = Graph(ros_context, setup, tmp_path, echo=False)
    try:
        g.start_coordinator(apply_timeout_s=0.5)
        t0 = time.monotonic()
        r = g.iterate()
        assert not r.success and 'fan_output running' in r.message
        assert time.monotonic() - t0 < 5.0
        assert g.status().state == IterationStatus.STATE_FAILED
        assert g.store().last_completed() == -1
    finally:
        g.close()


def test_iteration_timeout_from_the_request(graph):
    graph.start_coordinator(sweep_duration_s=5.0)
    t0 = time.monotonic()
    r = graph.iterate(timeout_s=1.0)
    assert not r.success and 'timed out while sweeping' in r.message, r.message
    assert time.monotonic() - t0 < 3.0
    # a failed iteration (a warning) and then a cancelled one (information): both answered
    running = graph.call_async(graph.run, RunIteration.Request())
    assert wait_until(lambda: graph.status().state == IterationStatus.STATE_SWEEPING)
    assert graph.call(graph.cancel, Trigger.Request()).success
    assert wait_until(running.done, timeout=3.0), 'the cancelled iteration did not answer'
    assert not running.result().success and 'cancelled' in running.result().message


@pytest.mark.slow
def test_one_iteration_with_the_real_field_estimator(ros_context, setup, tmp_path):
    g = Graph(ros_context, setup, tmp_path, estimator=False, stream=True)
    try:
        g.rig.sink = g.add_node(FieldEstimatorNode(context=ros_context, parameter_overrides=[
            Parameter("journal_dir", value=str(tmp_path / "journal"))]))
        g.start_coordinator(sweep_duration_s=1.0)
        r = g.iterate()
        assert r.success, r.message
        history = g.store().load_history()
        assert len(history[0].sweep) == 300  # one pair per pose
        assert r.rmse_predicted_after < r.rmse_before
    finally:
        g.close()


# -- the CLI (wind-shaper iterate / status / cancel) against the same in-process graph -----------
def test_cli_iterate_status_and_cancel(graph, capsys, paper_config):
    graph.start_coordinator(config_dir=paper_config)
    assert cli(['iterate', '--count', '2', '--gain', '0.6']) == 0
    out = capsys.readouterr().out
    assert 'k= 0  RMSE' in out and 'k= 1  RMSE' in out and '-> predicted' in out
    assert 'sweeping' in out and 'record: ' in out and 'LM1 50.0->' in out
    assert graph.store().last_completed() == 1
    assert graph.store().load_record(1)['step_size'] == pytest.approx(0.3)
    assert cli(['status']) == 0
    out = capsys.readouterr().out
    assert 'coordinator: done, iteration 1' in out and 'target: parabolic' in out
    assert cli(['cancel']) == 1
    assert 'no iteration or experiment is running' in capsys.readouterr().err
    assert cli(['iterate', '--target', 'gaussian@NOPE']) == 1
    assert 'NOPE' in capsys.readouterr().err
    assert graph.store().last_completed() == 1


def test_cli_set_model_swaps_the_prior_and_keeps_it_on_a_bad_file(graph, capsys, setup, tmp_path):
    node = graph.start_coordinator()
    model = setup.load_model()
    path = save_model(tmp_path / 'wider.yaml', model.k1.clone(sigma=0.2) + model.k2)
    assert cli(['set-model', str(path)]) == 0
    printed = capsys.readouterr().out
    assert 'now uses' in printed and 'sigma=0.2' in repr(node._run.model)
    assert f'prior set from {path} (sent as text)' in printed
    broken = tmp_path / 'broken.yaml'
    broken.write_text('wind_shaper_model: 1\nmodel: {kind: nope}\n')
    assert cli(['set-model', str(broken)]) == 1
    err = capsys.readouterr().err
    assert 'the old one stays' in err and 'sigma=0.2' in repr(node._run.model)
    assert err.count('model refused') == 1, err  # said once, with the reason
    assert "unknown model term kind 'nope'" in err and '--plugin FILE or WIND_SHAPER_PLUGINS' in err
    assert cli(['set-model', str(tmp_path / 'missing.yaml')]) == 2
    assert 'cannot read the model file' in capsys.readouterr().err


def test_cli_without_a_coordinator_says_how_to_start_one(ros_env, capsys):
    t0 = time.monotonic()
    assert cli(['iterate', '--wait', '0.5']) == 2
    err = capsys.readouterr().err
    assert ('no coordinator answered on /wind_shaper/run_iteration within 0.5 s: start the graph '
            'with `wind-shaper up --sim`') in err
    assert cli(['status', '--wait', '0.5']) == 2
    assert 'wind-shaper up --sim' in capsys.readouterr().err
    assert time.monotonic() - t0 < 5.0


def test_cli_help_shows_the_ros2_equivalent(capsys):
    with pytest.raises(SystemExit):
        cli(['iterate', '--help'])
    assert ('ros2 service call /wind_shaper/run_iteration wind_shaper_msgs/srv/RunIteration '
            '"{target: parabolic}"') in capsys.readouterr().out


# -- designed experiments (the collect service) ---------------------------------------------------
def collect_request(setup, spec='lhs:4', name='exp', **fields):
    from wind_shaper.experiment import make_design
    b = setup.shaping.bounds
    d = make_design(spec, setup.geometry.fans, b.u_min, b.u_max, seed=1)
    return d, Collect.Request(name=name, design=spec, fan_names=list(d.fan_names),
                              commands=[float(u) for u in d.commands.ravel()],
                              labels=list(d.labels), **fields)


def test_collect_runs_every_row_through_the_fans_then_turns_them_off(graph, setup):
    from wind_shaper.workbench.data import load_sweeps
    graph.start_coordinator()
    design, request = collect_request(setup)
    r = graph.call(graph.collect, request, timeout=40.0)
    assert r.success, r.message
    assert list(r.outcome) == ['stored'] * 4 and r.stored == 4 and list(r.coverage) == [1.0] * 4
    assert 'the fans are off' in r.message
    seen = np.array(graph.rig.commands)
    for row in design.commands:   # every row reached the fans, in order
        assert np.any(np.all(np.isclose(seen, row), axis=1))
    assert wait_until(lambda: np.allclose(graph.rig.commands[-1], 0.0), timeout=3.0)
    # the iteration status tells the truth about the fans: off
    assert wait_until(lambda: graph.status() is not None and np.allclose(graph.status().pwm, 0.0),
                      timeout=3.0)
    assert wait_until(lambda: len(graph.experiment_sweeps) == 4, timeout=3.0)
    assert [m.iteration for m in graph.experiment_sweeps] == [0, 1, 2, 3]
    states = {m.state for m in graph.experiment_statuses}
    assert states >= {'commanding', 'sweeping', 'checking', 'done'}
    assert graph.experiment_statuses[-1].stored == 4
    data = load_sweeps(r.run_folder, setup.geometry.fans.names)
    assert np.allclose(data.commands, design.commands)
    # the same request again: nothing left to sweep, nothing commanded but off
    n = graph.rig.sweeps
    again = graph.call(graph.collect, request, timeout=20.0)
    assert again.success and graph.rig.sweeps == n


def test_a_bad_design_is_refused_before_any_fan_moves(graph, setup):
    graph.start_coordinator()
    _, request = collect_request(setup)
    commands = list(request.commands)
    commands[9] = 0.97   # row 2, fan 3: above u_max
    request.commands = commands
    n = len(graph.rig.commands)
    r = graph.call(graph.collect, request)
    assert not r.success and 'no fan was commanded' in r.message and 'outside the configured range' in r.message
    assert graph.rig.sweeps == 0 and not (graph.run_root / 'exp').exists()
    assert all(np.allclose(c, graph.rig.commands[0]) for c in graph.rig.commands[n:])


def test_collect_and_iterate_never_run_at_once_and_cancel_stops_the_experiment(graph, setup):
    graph.start_coordinator(sweep_duration_s=2.0)
    _, request = collect_request(setup, 'lhs:5')
    future = graph.call_async(graph.collect, request)
    assert wait_until(lambda: any(m.state == 'sweeping' for m in graph.experiment_statuses))
    busy = graph.iterate()
    assert not busy.success and 'an experiment is running' in busy.message
    c = graph.call(graph.cancel, Trigger.Request())
    assert c.success and 'cancelling the experiment' in c.message
    assert wait_until(future.done, timeout=20.0)
    r = future.result()
    assert not r.success and 'cancelled' in r.message and 'pending' in list(r.outcome)
    assert wait_until(lambda: np.allclose(graph.rig.commands[-1], 0.0), timeout=3.0)
    assert graph.iterate().success   # the loop runs again once the experiment has ended
