"""Every benchmark script runs end to end at its quickest settings (seconds each), so a change
that breaks one (a swapped-in function that returns the wrong tuple, a renamed setting) fails
here, not when someone next runs it for a table. Scripts that need the ROS node graph or minutes
even at their smallest are listed with the reason; a new script must join one of the two lists."""
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_module import BENCH, load_bench  # noqa: E402

#: script -> its quickest arguments (the results file is added: --json in tmp_path)
QUICK = {
    'coverage': ['--effects', 'background_draft', '--sizes', '1', '--seeds', '1', '--clean', '1',
                 '--sweeps', '6', '--samples', '300', '--jobs', '1'],
    'field_std': ['--quick', '--estimator', 'long_run_span_s=0'],
    'scale': ['--quick'],
    'convergence': ['--quick', '--seeds', '1', '--iterations', '1', '--methods', 'warm+short',
                    '--targets', 'uniform'],
    'random_tunnels': ['--quick'],
    'clocks': ['--quick', '--jobs', '1'],
    'detection': ['--seeds', '1', '--kinds', 'clean', '--counts', '6', '--jobs', '1'],
    'diagnosis_speed': ['--quick'],
    'paper_cases': ['--seeds', '1', '--iterations', '2', '--cases', '1'],
}
#: script -> why the smoke test leaves it out
NOT_QUICK = {
    'commissioning': 'designed sweeps through the node graph (or minutes in-process)',
    'faults': 'fault injection through the node graph',
    'force_stream': 'the ROS force stream at kHz rates (several processes)',
    'kill_loop': 'kills nodes of the node graph tens of times: minutes',
    'fuzz': 'runs at its quickest in test/fuzz/test_fuzz.py (two targets, two examples)',
    'hosts': 'the node graph across processes',
    'iteration_split': 'runs wind-shaper up (six processes)',
    'replay_timing': 'replays bags through ROS nodes',
    'suggest': ('three diagnoses and the suggestion search: 90 s even at one effect and one seed '
                '(--seeds 1 --effects weak_fan)'),
}


def test_every_bench_script_is_listed():
    scripts = {p.stem for p in BENCH.glob('*.py')}
    assert scripts == set(QUICK) | set(NOT_QUICK), (
        f'new or removed bench scripts: {sorted(scripts ^ (set(QUICK) | set(NOT_QUICK)))}; add each '
        f'to QUICK (with its quickest arguments) or NOT_QUICK (with the reason)')


@pytest.mark.parametrize('name', sorted(QUICK))
def test_bench_script_runs_at_its_quickest(name, tmp_path, monkeypatch):
    module = load_bench(name)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / f'{name}.json'
    args = list(QUICK[name]) + ['--json', str(out)]
    if name == 'convergence':
        # zeta* from a cache: the smoke test checks that the loop runs, not the optimum
        cache = tmp_path / 'zeta.json'
        cache.write_text(json.dumps({'nominal, uniform': [0.08, [0.5] * 7]}))
        args += ['--zeta-cache', str(cache)]
    module.main(args)
    assert out.is_file() and json.loads(out.read_text())


def test_the_convergence_summary_table_comes_from_the_results_file(tmp_path, capsys):
    """docs/benchmarks.md's table is printed from the committed results file, one row per case."""
    results = BENCH / 'out' / 'convergence.json'
    load_bench('convergence').main(['--summary-from', str(results)])
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith('| ')]
    cases = json.loads(results.read_text())['cases']
    assert len(rows) == 1 + len(cases) and rows[1].startswith(f"| {cases[0]['case']} |")
