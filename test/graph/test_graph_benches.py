"""The benchmark scripts that start ROS processes, the node graph or network namespaces, each at
its quickest settings (test/bench_module.py's GRAPH_QUICK), so that none rots between the runs
that fill the benchmarks page. Each also checks that its figures are figures: a stream that
counts samples counted more than one, an iteration that was split has its phases."""
import json
import sys
from pathlib import Path

import pytest
from netns_required import require_netns

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_module import GRAPH_QUICK, load_bench  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def run(name: str, tmp_path: Path, monkeypatch, *extra: str) -> dict:
    monkeypatch.chdir(tmp_path)
    out = tmp_path / f'{name}.json'
    args = [*GRAPH_QUICK[name], *extra, '--json', str(out)]
    code = load_bench(name).main(args)
    assert out.is_file(), f'bench/{name}.py {" ".join(args)} wrote no results (exit code {code})'
    return {'code': code, **json.loads(out.read_text())}


def test_every_graph_bench_has_a_check_here():
    checked = {n[len('test_'):].removesuffix('_runs_at_its_quickest') for n in globals()
               if n.endswith('_runs_at_its_quickest')}
    assert checked == set(GRAPH_QUICK)


def test_force_stream_runs_at_its_quickest(tmp_path, monkeypatch, ros_env):
    r = run('force_stream', tmp_path, monkeypatch)
    (row,) = r['rows']
    assert row['sent'] > 100 and row['received'] > 100, row


def test_iteration_split_runs_at_its_quickest(tmp_path, monkeypatch, ros_env):
    r = run('iteration_split', tmp_path, monkeypatch)
    assert r['code'] == 0
    assert set(r['phases']) >= {'commanding', 'sweep', 'estimation', 'update + record'}
    assert r['phases']['sweep']['median_ms'] > 2500   # at least one 3 s sweep (more fill gaps)


def test_kill_loop_runs_at_its_quickest(tmp_path, monkeypatch, ros_env):
    # whether the killed node recovered is the bench's figure (a rare failure is what it
    # measures); that it killed one in the middle of a sweep is checked here
    r = run('kill_loop', tmp_path, monkeypatch, '--domain', ros_env['ROS_DOMAIN_ID'])
    (row,) = r['rows']
    assert row['node'] == 'mocap_relay' and row['sweep_started'], row


def test_hosts_runs_at_its_quickest(tmp_path, monkeypatch):
    require_netns('bench/hosts.py')
    r = run('hosts', tmp_path, monkeypatch)
    for row in r['stream']:
        assert 'error' not in row and row['sent'] > 100, row
    assert r['cloud']['clouds'] >= 1 and r['cloud']['points'] > 0, r['cloud']


def test_commissioning_runs_at_its_quickest(tmp_path, monkeypatch, ros_env):
    r = run('commissioning', tmp_path, monkeypatch)
    arms = [row['arm'] for row in r['rows']]
    assert 'designed lhs:3' in arms, arms
    assert all(0 < row['heldout_rmse_N'] < 10 for row in r['rows']), r['rows']
