"""core.limits and core.safe_yaml: every YAML text and request field is bounded before parsing.

Each hostile input here is one a user on the shared ROS domain sent to the graph and took it
down or wedged it: the refusal must come at once, say what to do, and quote a short excerpt."""
import time
import tracemalloc

import numpy as np
import pytest
import yaml

from wind_shaper.coordination.requests import (check_collect_request, check_model_request,
                                               check_target_request)
from wind_shaper.core.errors import LimitError, ModelFileError
from wind_shaper.core.geometry import TunnelGeometry
from wind_shaper.core.limits import DEFAULT_LIMITS, EXCERPT_CHARS, Limits, excerpt
from wind_shaper.core.safe_yaml import YamlRefused, load_yaml, read_text_file, read_yaml_file
from wind_shaper.model.modelfile import model_from_text

#: Longest refusal message: what was wrong, what to do, an excerpt, never the input itself.
MAX_MESSAGE = 600


def alias_bomb(levels=9, fan_out=9) -> str:
    """A 1 KB YAML text whose aliases expand to fan_out ** levels strings."""
    lines = ['wind_shaper_model: 1', 'a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(1, levels + 1):
        lines.append(f'a{i}: &a{i} [' + ', '.join([f'*a{i - 1}'] * fan_out) + ']')
    lines.append(f'model: *a{levels}')
    return '\n'.join(lines) + '\n'


@pytest.fixture(scope='module')
def fans():
    return TunnelGeometry.paper_rig().fans


def refused_quickly(call, *args, error=LimitError, within_s=2.0):
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(error) as info:
            call(*args)
        elapsed = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    message = str(info.value)
    assert len(message) < MAX_MESSAGE, message
    return message, elapsed, peak


def test_the_alias_bomb_is_refused_before_it_expands(fans):
    text = alias_bomb()
    assert len(text) < 1100
    message, _, peak = refused_quickly(model_from_text, text, fans, error=ModelFileError)
    assert 'anchors or aliases' in message and 'lol' not in message
    assert peak < 5e6, peak


def test_fifty_thousand_nested_brackets_are_refused_without_recursion(fans):
    text = 'wind_shaper_model: 1\nmodel: ' + '[' * 50_000 + ']' * 50_000
    message, _, _ = refused_quickly(model_from_text, text, fans, error=ModelFileError)
    assert 'deeper than 40 levels' in message


def test_twenty_megabytes_of_text_are_refused_by_their_size(fans):
    text = 'wind_shaper_model: 1\nmodel: "' + 'x' * 20_000_000 + '"\n'
    message, elapsed, _ = refused_quickly(model_from_text, text, fans, error=ModelFileError)
    assert 'limits.yaml_bytes' in message and 'xxxxxxxxxx' not in message
    assert len(message) < 300


@pytest.mark.parametrize('text, words', [
    ('a: 9' + '9' * 100_000, 'cannot be read'),        # int() of 100,000 digits
    ('a: 2001-13-45', 'month must be in 1..12'),
    ('a: [1, 2', 'not readable YAML'),
    ('!!python/object:os.system {}', 'not readable YAML'),
    ('a: "\ud800"', 'not valid Unicode'),
    (b'a: \xff\xfe', 'not UTF-8'),
])
def test_values_python_cannot_build_are_refused_as_yaml_errors(text, words):
    with pytest.raises(yaml.YAMLError) as info:
        load_yaml(text, 'the text')
    assert words in str(info.value) and len(str(info.value)) < MAX_MESSAGE


def test_plain_yaml_still_reads():
    assert load_yaml('a: [1, 2.5, {b: c}]\nd: null\n') == {'a': [1, 2.5, {'b': 'c'}], 'd': None}
    assert load_yaml('[' * 40 + ']' * 40) is not None        # exactly the depth allowed


def test_a_large_text_is_built_without_a_collector_pass_and_the_collector_state_comes_back():
    """A collector pass over a large document's objects holds the GIL for a second or more on a
    busy machine: a node reading it in a worker thread stopped answering cancel meanwhile."""
    import gc
    text = 'notes:\n' + '- [0.123456789, 0.987654321, 0.5]\n' * 20000
    passes = []

    def count(phase, info):
        # the event check's short-lived objects may take a youngest-generation pass (cheap);
        # passes over older generations are the ones that walk the document (the old code: 39)
        if phase == 'start' and info['generation'] > 0:
            passes.append(info['generation'])
    was_enabled = gc.isenabled()
    gc.callbacks.append(count)
    try:
        for enabled in (True, False):
            (gc.enable if enabled else gc.disable)()
            # the collector's counters start from zero: what earlier tests left in them took
            # a youngest-but-one pass during the event check once (CI)
            gc.collect()
            passes.clear()
            assert len(load_yaml(text)['notes']) == 20000
            assert passes == [] and gc.isenabled() == enabled
        gc.enable()
        with pytest.raises(YamlRefused):      # a refused read restores it as well
            load_yaml('a: [1, 2\n')
        assert gc.isenabled()
    finally:
        gc.callbacks.remove(count)
        (gc.enable if was_enabled else gc.disable)()


def test_files_are_read_only_within_their_bound(tmp_path):
    big = tmp_path / 'big.yaml'
    big.write_bytes(b'a: ' + b'1' * (DEFAULT_LIMITS.yaml_bytes + 10))
    with pytest.raises(YamlRefused, match='limits.yaml_bytes'):
        read_yaml_file(big)
    with pytest.raises(LimitError, match='larger than 100 bytes'):
        read_text_file(big, 100)
    ok = tmp_path / 'ok.yaml'
    ok.write_text('a: 1\n')
    assert read_yaml_file(ok) == {'a': 1}


def test_an_excerpt_is_short_and_says_how_long_the_whole_was():
    text = excerpt('y' * 10_000)
    assert len(text) < EXCERPT_CHARS + 40 and '10000 characters' in text
    assert excerpt('short') == "'short'"


def test_a_design_above_the_plate_budget_is_refused_with_its_plate_time():
    fans = [f'F{i}' for i in range(7)]
    commands = np.zeros(200_000 * 7).tolist()
    with pytest.raises(LimitError) as info:
        check_collect_request(DEFAULT_LIMITS, 'exp', 'lhs', fans, commands, [], 22.0)
    message = str(info.value)
    assert '200000 sweeps' in message and '50 d 22 h' in message and 'budget' in message
    # a table within the budget states its plate time
    assert check_collect_request(DEFAULT_LIMITS, 'exp', 'lhs', fans, [0.0] * 70, [], 22.0) == 220.0
    small = Limits(plate_budget_s=100.0)
    with pytest.raises(LimitError, match='plate time'):
        check_collect_request(small, 'exp', 'lhs', fans, [0.0] * 70, [], 22.0)


@pytest.mark.parametrize('call, args, words', [
    (check_target_request, ('expr:' + 'x+' * 5000,), 'the target has 10005 characters'),
    (check_model_request, ('a' * 2_000_000, ''), 'limits.yaml_bytes'),
    (check_model_request, ('', '/' * 5000), 'the path has 5000 characters'),
    (check_collect_request, ('e' * 300, '', ['F'], [0.5], [], 1.0), 'experiment name'),
    (check_collect_request, ('e', '', ['F' * 300], [0.5], [], 1.0), 'a name in fan_names'),
    (check_collect_request, ('e', '', [f'F{i}' for i in range(100)], [0.5] * 100, [], 1.0),
     'fan_names has 100 entries'),
    (check_collect_request, ('e', '', ['F'], [0.5] * 3, ['l'] * 5000, 1.0), 'labels has 5000'),
])
def test_every_request_field_has_a_bound(call, args, words):
    with pytest.raises(LimitError) as info:
        call(DEFAULT_LIMITS, *args)
    assert words in str(info.value) and len(str(info.value)) < MAX_MESSAGE


def test_limits_outside_their_range_are_refused():
    with pytest.raises(LimitError, match='limits.yaml_depth'):
        Limits(yaml_depth=1)
