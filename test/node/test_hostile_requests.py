"""The coordinator and field_estimator in-process under the hostile requests a user on the shared
ROS domain sent them: each is answered with a short refusal that says what to do, the node goes
on serving (cancel answers while a large request is read), and its memory stays bounded.

One test per finding: an alias bomb as set_model text (the coordinator grew to 8.4 GB), 50,000
nested brackets (it died of RecursionError), 20 MB of text (seconds on the executor), a collect
of 200,000 rows (accepted, then wedged for good), a field query of 5 million points (computed
before it was refused)."""
import resource
import statistics
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from std_srvs.srv import Trigger  # noqa: E402
from wind_shaper_msgs.srv import Collect, QueryField, RunIteration, SetModel  # noqa: E402

from test_coordinator import Graph, setup, wait_until  # noqa: E402,F401 - fixtures and helpers
from wind_shaper.nodes.field_estimator import FieldEstimatorNode  # noqa: E402
from wind_shaper.ros import names  # noqa: E402

pytestmark = pytest.mark.ros

#: Longest refusal message: what was wrong and what to do, an excerpt at most.
MAX_MESSAGE = 1500
MB = 1 << 20


def alias_bomb(levels=9, fan_out=9) -> str:
    lines = ['wind_shaper_model: 1',
             'a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(1, levels + 1):
        lines.append(f'a{i}: &a{i} [' + ', '.join([f'*a{i - 1}'] * fan_out) + ']')
    lines.append(f'model: *a{levels}')
    return '\n'.join(lines) + '\n'


def rss_bytes() -> int:
    with open('/proc/self/statm') as f:
        return int(f.read().split()[1]) * resource.getpagesize()


@pytest.fixture
def graph(ros_context, setup, tmp_path):   # noqa: F811 - the fixture of test_coordinator
    g = Graph(ros_context, setup, tmp_path)
    yield g
    g.close()


def answered(graph, client, request, timeout=30.0):
    """(response, seconds to answer); fails when no answer came within ``timeout``."""
    t0 = time.monotonic()
    response = graph.call(client, request, timeout=timeout)
    return response, time.monotonic() - t0


def still_serving(graph):
    """The coordinator still answers: a cancel with nothing running says so."""
    r, _ = answered(graph, graph.cancel, Trigger.Request(), timeout=10.0)
    assert not r.success and 'no iteration or experiment is running' in r.message


def test_an_alias_bomb_as_set_model_text_is_refused_at_once(graph):
    graph.start_coordinator()
    before = rss_bytes()
    r, _ = answered(graph, graph.set_model, SetModel.Request(model_yaml=alias_bomb()))
    assert not r.success and 'anchors or aliases' in r.message, r.message[:500]
    assert len(r.message) < MAX_MESSAGE and 'lol' not in r.message
    assert rss_bytes() - before < 50 * MB
    still_serving(graph)


def test_fifty_thousand_nested_brackets_are_refused_and_the_coordinator_lives_on(graph):
    graph.start_coordinator()
    text = 'wind_shaper_model: 1\nmodel: ' + '[' * 50_000 + ']' * 50_000
    r, _ = answered(graph, graph.set_model, SetModel.Request(model_yaml=text))
    assert not r.success and 'deeper than' in r.message, r.message[:500]
    assert len(r.message) < MAX_MESSAGE
    still_serving(graph)


def test_twenty_megabytes_of_model_text_are_refused_by_their_size(graph):
    graph.start_coordinator()
    text = 'wind_shaper_model: 1\nmodel: "' + 'x' * 20_000_000 + '"\n'
    r, _ = answered(graph, graph.set_model, SetModel.Request(model_yaml=text), timeout=60.0)
    assert not r.success and 'limits.yaml_bytes' in r.message, r.message[:500]
    assert len(r.message) < MAX_MESSAGE and 'xxxxxxxxxx' not in r.message
    still_serving(graph)


def test_a_collect_of_200000_rows_is_refused_with_its_plate_time(graph):
    graph.start_coordinator()
    fans = list(graph.rig.fans)
    commands = np.zeros((200_000, len(fans))).ravel().tolist()
    r, _ = answered(graph, graph.collect, Collect.Request(name='huge', design='hostile',
                                                          fan_names=fans, commands=commands),
                    timeout=60.0)
    assert not r.success and '200000 sweeps' in r.message and 'plate time' in r.message, \
        r.message[:500]
    assert 'no fan was commanded' in r.message and len(r.message) < MAX_MESSAGE
    assert not (graph.run_root / 'huge').exists()
    still_serving(graph)


def test_cancel_goes_on_while_the_largest_model_text_is_read(graph):
    """The largest set_model text the limits accept (just under limits.yaml_bytes, a model file
    with a long list beside it) takes seconds to read: meanwhile the coordinator answers cancel
    within 1 s (the median of the calls made while it reads)."""
    coordinator = graph.start_coordinator()
    limit = coordinator.limits.yaml_bytes
    model = (graph.setup.config_dir / 'model.yaml').read_text()
    row = '- [0.123456789, 0.987654321, 0.5]\n'
    text = model + 'notes:\n' + row * ((limit - len(model) - 10) // len(row))
    assert limit - 200 < len(text.encode()) <= limit
    future = graph.call_async(graph.set_model, SetModel.Request(model_yaml=text))
    waits, t_start = [], time.monotonic()
    while not future.done() and time.monotonic() - t_start < 120:
        _, seconds = answered(graph, graph.cancel, Trigger.Request(), timeout=10.0)
        waits.append(seconds)
        time.sleep(0.2)
    assert wait_until(future.done, 120)
    reading_s = time.monotonic() - t_start
    assert future.result().success, future.result().message[:500]
    assert len(waits) >= 3, f'the text was read in {reading_s:.1f} s: too fast to measure'
    assert statistics.median(waits) < 1.0, waits
    print(f'set_model of {len(text)} bytes: read in {reading_s:.1f} s; cancel answered in '
          f'{statistics.median(waits) * 1000:.0f} ms (median of {len(waits)}, longest '
          f'{max(waits) * 1000:.0f} ms)')


def test_a_field_query_of_five_million_points_is_refused_by_its_size(ros_context, setup, tmp_path):
    from test_coordinator import spin   # noqa: F811
    estimator = FieldEstimatorNode(context=ros_context, parameter_overrides=[
        rclpy.parameter.Parameter('journal_dir', value='')])
    executor, thread = spin(estimator, ros_context)
    client_node = rclpy.create_node('query_client', context=ros_context)
    cexec, cthread = spin(client_node, ros_context)
    try:
        client = client_node.create_client(QueryField, names.QUERY_FIELD)
        assert client.wait_for_service(timeout_sec=15)
        xy = np.zeros(5_000_000).tolist()
        future = client.call_async(QueryField.Request(x=xy, y=xy))
        assert wait_until(future.done, 60)
        r = future.result()
        assert not r.success and '5000000 entries' in r.message and 'limits.query_points' in r.message
    finally:
        for t, ex, node in ((thread, executor, estimator), (cthread, cexec, client_node)):
            t.stop.set()
            t.join(timeout=15)
            ex.shutdown(timeout_sec=15)
            node.destroy_node()


def test_a_target_of_ten_thousand_characters_is_refused(graph):
    graph.start_coordinator()
    r, _ = answered(graph, graph.run, RunIteration.Request(target='expr:' + 'x+' * 5000 + '1'))
    assert not r.success and 'limits.text_chars' in r.message and len(r.message) < MAX_MESSAGE
    still_serving(graph)
