"""Every benchmark script runs end to end at its quickest settings (seconds each), so a change
that breaks one (a swapped-in function that returns the wrong tuple, a renamed setting) fails
here, not when someone next runs it for a table. Scripts that start the node graph run in the
graph tier (test/graph/test_graph_benches.py); a new script must join one of the lists of
test/bench_module.py."""
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_module import BENCH, ELSEWHERE, GRAPH_QUICK, QUICK, load_bench  # noqa: E402


def test_every_bench_script_is_listed_once():
    scripts = {p.stem for p in BENCH.glob('*.py')}
    lists = (QUICK, GRAPH_QUICK, ELSEWHERE)
    listed = [name for names in lists for name in names]
    assert scripts == set(listed) and len(listed) == len(set(listed)), (
        f'new, removed or twice-listed bench scripts: {sorted(scripts ^ set(listed))}; add each '
        f'to one of QUICK, GRAPH_QUICK (with its quickest arguments) or ELSEWHERE (with its test) '
        f'in test/bench_module.py')


@pytest.mark.parametrize('name', sorted(QUICK))
def test_bench_script_runs_at_its_quickest(name, tmp_path, monkeypatch, ros_env):
    module = load_bench(name)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / f'{name}.json'
    args = list(QUICK[name]) + ['--json', str(out)]
    if name == 'convergence':
        # zeta* from a cache: the smoke test checks that the loop runs, not the optimum
        cache = tmp_path / 'zeta.json'
        cache.write_text(json.dumps({'nominal, uniform': [0.08, [0.5] * 7]}))
        args += ['--zeta-cache', str(cache)]
    code = module.main(args)   # an exit code, or (field_std) the figures
    assert not (isinstance(code, int) and code), f'bench/{name}.py {" ".join(args)} exited with {code}'
    assert out.is_file() and json.loads(out.read_text())


def test_the_convergence_summary_table_comes_from_the_results_file(tmp_path, capsys):
    """docs/benchmarks.md's table is printed from the committed results file, one row per case."""
    results = BENCH / 'out' / 'convergence.json'
    load_bench('convergence').main(['--summary-from', str(results)])
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith('| ')]
    cases = json.loads(results.read_text())['cases']
    assert len(rows) == 1 + len(cases) and rows[1].startswith(f"| {cases[0]['case']} |")
