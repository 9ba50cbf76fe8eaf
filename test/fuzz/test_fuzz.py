"""The fuzz tier: every service request and every file wind_shaper reads, under hypothesis.

Each example must end in a result or a short refusal (a WindShaperError or yaml.YAMLError),
never another exception, a hang (pytest-timeout) or a long message. CI runs a few examples of
each (WIND_SHAPER_FUZZ_EXAMPLES, default 20: a few seconds per target); bench/fuzz.py runs
thousands and prints what it tried."""
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from targets import NAMES, strategies

EXAMPLES = int(os.environ.get('WIND_SHAPER_FUZZ_EXAMPLES') or 20)


@pytest.fixture(scope='module')
def targets():
    return strategies()


@pytest.mark.parametrize('name', NAMES)
def test_every_input_ends_in_a_result_or_a_clear_refusal(targets, name):
    strategy, target = targets[name]

    # reading a bag takes about a second: fewer of those
    @settings(max_examples=max(EXAMPLES // 4, 2) if name == 'bag' else EXAMPLES, deadline=None, database=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(st.data())
    def check(data):
        assert target(data.draw(strategy)) in ('ok', 'refused')

    check()


def test_the_long_fuzz_run_works_at_its_quickest(tmp_path, capsys):
    """bench/fuzz.py at 2 examples of two targets: its table and its figures."""
    import json
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from bench_module import load_bench
    out = tmp_path / 'fuzz.json'
    code = load_bench('fuzz').main(['--examples', '2', '--only', 'design CSV', '--only',
                                    'set_model request', '--json', str(out)])
    assert code == 0, capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert [r['target'] for r in doc['targets']] == ['design CSV', 'set_model request']
    assert all(r['tried'] >= 1 and not r['crash'] for r in doc['targets'])
    assert 'resident memory grew' in capsys.readouterr().out


@pytest.mark.ros
def test_the_coordinators_memory_run_works_at_its_quickest(tmp_path, capsys, ros_env):
    """bench/fuzz.py --coordinator 2: a coordinator process answers every hostile request, and
    its memory is printed."""
    import json
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from bench_module import load_bench
    out = tmp_path / 'fuzz.json'
    code = load_bench('fuzz').main(['--coordinator', '2', '--only', 'none', '--json', str(out)])
    printed = capsys.readouterr().out
    assert code == 0, printed
    node = json.loads(out.read_text())['coordinator']
    assert node['alive'] and node['unanswered'] == 0 and node['requests'] >= 8, node
    assert 'coordinator: ' in printed and 'resident memory' in printed
