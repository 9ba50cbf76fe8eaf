"""The random-tunnel benchmark's draw: reproducible, every drawn tunnel one the simulator
builds (each parameter inside its effect's bounds), and every flow effect of the simulator
in the catalogue, so an effect added later is drawn too or left out with a reason."""
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.sim import HIDDEN_EFFECTS
from wind_shaper.sim.effects import effects_from_config

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_module import load_bench  # noqa: E402

bench = load_bench('random_tunnels')


def test_the_draw_depends_on_the_seed_alone():
    a, b = bench.draw_tunnels(5, 7, 3), bench.draw_tunnels(5, 7, 3)
    assert a == b
    assert a != bench.draw_tunnels(5, 8, 3)
    for tunnel in a:
        names = [e['name'] for e in tunnel['effects']]
        assert len(names) == 3 == len(set(names))
        assert tunnel['name'].endswith(' + '.join(names))


def test_every_drawn_tunnel_is_one_the_simulator_builds():
    setup = Setup.load()
    assert tuple(bench.FANS) == tuple(setup.geometry.fans.names)
    for seed in range(40):
        for tunnel in bench.draw_tunnels(4, seed, 3):
            sim = setup.make_sim(seed=0, effects=list(effects_from_config(tunnel['effects'])))
            assert np.all(np.isfinite(sim.true_field(np.full(7, 0.4), setup.geometry.key_points)))


def test_every_flow_effect_of_the_simulator_is_drawn_or_left_out_with_a_reason():
    shipped = {name for name, cls in HIDDEN_EFFECTS.items() if cls.__module__.startswith('wind_shaper.sim')}
    assert not set(bench.CATALOGUE) & set(bench.LEFT_OUT)
    assert shipped == set(bench.CATALOGUE) | set(bench.LEFT_OUT), sorted(
        shipped ^ (set(bench.CATALOGUE) | set(bench.LEFT_OUT)))


@pytest.mark.parametrize('args, says', [(['--effects', '0'], '--effects'),
                                        (['--set', 'bogus=1'], 'bogus'),
                                        (['--set', 'load_sd'], 'NAME=VALUE'),
                                        (['--methods', 'warm+short,sideways'], 'sideways'),
                                        (['--targets', 'uniform,lopsided'], 'lopsided')])
def test_a_bad_argument_is_refused_before_any_run_with_what_was_wrong(args, says, capsys, tmp_path):
    with pytest.raises(SystemExit):
        bench.main(args + ['--json', str(tmp_path / 'out.json')])
    assert says in capsys.readouterr().err
    assert not (tmp_path / 'out.json').exists() and not (tmp_path / 'random_tunnels').exists()


def test_the_docs_tables_come_from_the_results_files(capsys):
    """docs/benchmarks.md's random-tunnel tables are printed from the committed results files,
    one row per case, the paper's column (not run) left out."""
    docs = (Path(__file__).resolve().parents[2] / 'docs' / 'benchmarks.md').read_text()
    for name in ('random_tunnels.json', 'random_tunnels_2027.json', 'random_tunnels_2028.json',
                 'random_tunnels_2029.json'):
        path = Path(bench.__file__).parent / 'out' / name
        bench.main(['--summary-from', str(path)])
        printed = capsys.readouterr().out.split('| case | shipped (warm start)')[1]
        rows = [line for line in printed.splitlines() if line.startswith('| random')]
        cases = json.loads(path.read_text())['cases']
        assert len(rows) == len(cases) == 36
        for row in rows:
            cells = row.split(' | ')
            assert ' | '.join(cells[:3] + cells[4:]) in docs, cells[0]


def test_the_shared_curve_verdict_names_the_tunnels_where_the_setting_changes_a_run(tmp_path, capsys):
    """A drawn stall dip every fan shares is bent; a tunnel without one is not, and the file
    says so per tunnel."""
    out = tmp_path / 'verdicts.json'
    bench.main(['--seed', '2033', '--quick', '--shared-curve-verdicts', '--json', str(out)])
    assert json.loads(out.read_text())['shared_curve'] == {
        'random 2033-0: coflow_carry + vane_ripple + diffuser_separation': False}
    assert 'straight' in capsys.readouterr().out
    dipped = bench.draw_tunnels(8, 2033, 3)[7]
    assert 'stall_dip' in dipped['name']
    assert bench.shared_curve_verdict((dipped, {'method': 'adaptive', 'shared_curve_sd': 0.1}))
