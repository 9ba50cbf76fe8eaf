"""The model workbench as a user drives it: `wind-shaper model ...` on the simulated tunnel, and
the whole way through a bag (record sweeps, diagnose from the bag, add the effect, rerun)."""
import json

import pytest
import yaml

from wind_shaper.cli.main import main


def _summary(out):
    return json.loads((out / 'summary.json').read_text())


@pytest.mark.slow
def test_diagnose_then_add_on_the_simulator(tmp_path, capsys):
    hidden = ['--sim', '--hidden', 'tilted_fan:fan=LM2,shift=0.04/0', '--seed', '5']
    diag = tmp_path / 'diag'
    assert main(['model', 'diagnose', *hidden, '--out', str(diag), '--suggest', '3']) == 0
    printed = capsys.readouterr().out
    assert 'the jet of fan LM2 lands' in printed and 'report:' in printed
    # the suggested follow-up is a design `wind-shaper collect` runs (checked, nothing moves)
    assert f'wind-shaper collect --design {diag / "suggested_design.csv"}' in printed
    assert main(['collect', '--design', str(diag / 'suggested_design.csv'), '--out', 'next',
                 '--dry-run']) == 0
    assert 'suggested 3' in capsys.readouterr().out
    doc = _summary(diag)
    assert doc['verdict'] == 'found' and doc['findings'][0]['candidate'] == 'fan_shift[LM2]'
    assert len(doc['suggestion']['commands']) == 3 and doc['suggestion']['goal'] in ('separate', 'shrink')
    assert doc['truth'] == [{'name': 'tilted_fan', 'fan': 'LM2', 'shift': [0.04, 0.0]}]
    html = (diag / 'report.html').read_text()
    assert html.count('data:image/png;base64,') >= 4 and 'Against the simulator' in html
    for png in ('diagnosis_maps.png', 'diagnosis_fans.png', 'diagnosis_radial.png', 'ranking_step1.png'):
        assert (diag / png).read_bytes()[:4] == b'\x89PNG'

    add, model = tmp_path / 'add', tmp_path / 'improved.yaml'
    assert main(['model', 'add', *hidden, '--from-diagnosis', str(diag / 'summary.json'),
                 '--save', str(model), '--closed-loop', 'gaussian@LM2', '--rule', 'paper', '--u0', '0.5',
                 '--out', str(add)]) == 0
    doc = _summary(add)
    assert doc['heldout_drop'] >= 0.5 and doc['after']['heldout_model_rmse_N'] < doc['before']['heldout_model_rmse_N']
    loop = doc['closed_loop']['median_true_rmse_N']
    assert loop['after (refitted)'][6] < loop['before'][6]
    assert (add / 'closed_loop.png').is_file() and 'fan_shift' in model.read_text()
    # the new model file is what `wind-shaper shape --model` takes
    assert main(['shape', '--sim', '--target', 'gaussian@LM2', '--iterations', '1', '--model', str(model),
                 '--out', str(tmp_path / 'shape')]) == 0


@pytest.mark.slow
def test_fit_and_compare_write_their_reports(tmp_path, capsys):
    fit = tmp_path / 'fit'
    assert main(['model', 'fit', '--sim', '--sweeps', '6', '--samples', '1000', '--out', str(fit),
                 '--save', str(tmp_path / 'fitted.yaml')]) == 0
    doc = _summary(fit)
    assert doc['heldout']['model_rmse_N'] < 0.5 * doc['heldout']['noise_sd_N']
    # the sweeps' field maps kept beside the fitted model, as `calibrate --data` keeps them
    from wind_shaper.app import Setup
    maps, note = Setup.load().prior_maps(tmp_path / 'fitted.yaml')
    assert note == '' and len(maps) >= 4
    assert set(doc['train_overall']) >= {'rmse', 'r2', 'max_error'} and doc['train_overall']['r2'] > 0.99
    assert all('std' in p for p in doc['fit']['parameters'].values())
    cmp = tmp_path / 'cmp'
    assert main(['model', 'compare', '--sim', '--sweeps', '6', '--model', 'config/model.yaml',
                 '--model', str(tmp_path / 'fitted.yaml'), '--out', str(cmp)]) == 0
    models = _summary(cmp)['models']
    assert models['fitted']['heldout_model_rmse_N'] < models['model']['heldout_model_rmse_N']
    assert 'held-out model error' in capsys.readouterr().out


def test_a_fit_with_nothing_held_out_says_so(tmp_path, capsys):
    assert main(['model', 'fit', '--sim', '--sweeps', '1', '--samples', '300', '--out', str(tmp_path / 'fit')]) == 0
    printed = capsys.readouterr().out
    assert 'nothing held out: 1 sweep (3 or more' in printed and 'collect --design lhs:6' in printed


@pytest.mark.parametrize('argv,message', [
    (['model', 'diagnose'], '--sim'),
    (['model', 'diagnose', '--sim', '--hidden', 'warp_drive'], 'warp_drive'),
    (['model', 'add', '--sim', '--effect', 'fan_gain[NOPE]'], 'fan_gain[NOPE]'),
    (['model', 'diagnose', '--data', 'no/such/bag'], 'does not exist'),
    (['model', 'add', '--sim'], 'nothing to add'),
    (['model', 'diagnose', '--sim'], '3 sweeps are too few for a diagnosis'),
])
def test_bad_input_is_named(argv, message, capsys, tmp_path):
    assert main(argv + ['--sweeps', '3', '--samples', '60', '--out', str(tmp_path / 'o')]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.slow
def test_the_readme_steps_on_the_simulator(tmp_path, capsys):
    """The README's steps: diagnose the weak fan, add it, shape the same tunnel (--hidden) with the
    improved model: its warm start (k = 0) tracks better than the reference's. Adding the same
    effect on a tunnel without it shows the refitted value (gain about 1) and claims no drop below
    the noise level."""
    weak = ['--sim', '--hidden', 'weak_fan:fan=HM2,gain=0.8']
    diag, improved = tmp_path / 'diag-sim', tmp_path / 'improved.yaml'
    assert main(['model', 'diagnose', *weak, '--out', str(diag)]) == 0
    assert _summary(diag)['findings'][0]['candidate'] == 'fan_gain[HM2]'
    assert main(['model', 'add', *weak, '--from-diagnosis', str(diag / 'summary.json'), '--save', str(improved),
                 '--out', str(tmp_path / 'add')]) == 0
    printed = capsys.readouterr().out
    assert 'added fan_gain[HM2] with gain 0.8' in printed and '% lower' in printed
    k1 = {}
    for label, model in (('improved', improved), ('reference', 'config/reference.yaml')):
        out = tmp_path / label
        assert main(['shape', '--target', 'gaussian@HM2', '--iterations', '1', '--model', str(model),
                     *weak, '--out', str(out)]) == 0
        runs = json.loads((out / 'run.json').read_text())['iterations']
        k1[label] = runs[0]['true_rmse_N']  # k = 0: the warm start
    assert k1['improved'] < k1['reference'] - 0.01, k1

    # the same addition on a tunnel without the weak fan: refitted, not the diagnosis's 0.81
    add = tmp_path / 'add-none'
    assert main(['model', 'add', '--sim', '--from-diagnosis', str(diag / 'summary.json'),
                 '--save', str(tmp_path / 'none.yaml'), '--out', str(add)]) == 0
    printed = capsys.readouterr().out
    doc = _summary(add)
    gain = doc['added_parameters'][0]['fitted']['gain']
    assert gain['value'][0] == pytest.approx(1.0, abs=0.05) and 0 < gain['std'][0] < 0.05
    assert doc['added'][0] == f'fan_gain[HM2] with gain {gain["value"][0]:.3f} ± {gain["std"][0]:.3f}'
    assert doc['below_noise_level'] and '% lower' not in printed and 'below the noise level' in printed
    assert f'Added: {doc["added"][0]}' in (add / 'report.md').read_text()
    saved = yaml.safe_load((tmp_path / 'none.yaml').read_text())['added'][0]
    assert saved['effect'] == 'fan_gain[HM2]' and saved['fitted (1 sigma)']['gain'] == gain


def test_adding_from_a_diagnosis_that_found_nothing_says_so(tmp_path, capsys):
    summary = tmp_path / 'summary.json'
    summary.write_text(json.dumps({'command': 'diagnose', 'verdict': 'explained', 'findings': []}))
    assert main(['model', 'add', '--sim', '--sweeps', '3', '--samples', '60', '--from-diagnosis', str(summary),
                 '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err
    assert (f'the diagnosis in {summary} found no effect and offered no formula or discrepancy term to add'
            in err and 'or --from-diagnosis' not in err and 'discrepancy to stand in' in err)
    assert not (tmp_path / 'o').exists()


@pytest.mark.slow
def test_the_whole_way_through_a_bag(tmp_path, capsys):
    """Record sweeps of a tunnel with a weak fan into a bag, diagnose from the bag, add the
    effect, and rerun: the new model predicts the held-out sweeps better and shapes better."""
    pytest.importorskip('rosbags', reason='bags need the rosbags package (tools/requirements.txt)')
    from wind_shaper.app import Setup
    from wind_shaper.bag.sweeps import write_sweep_bag
    from wind_shaper.sim import make_effect
    from wind_shaper.workbench.closed_loop import compare_closed_loop
    from wind_shaper.workbench.commands import simulated_sweeps
    setup = Setup.load()
    weak = make_effect('weak_fan', fan='HM2', gain=0.7)
    sweeps = simulated_sweeps(setup.make_sim(seed=7, effects=[weak]), 8, seed=7, n_samples=300)
    bag = write_sweep_bag(tmp_path / 'sweeps_bag', sweeps.sweeps, fan_names=setup.geometry.fans.names,
                          force_rate_hz=100.0, idle_streams=False, settle_s=0.1, gap_s=0.1)
    diag = tmp_path / 'diag'
    # 300-sample sweeps revisit too few places to measure the turbulence: give it
    assert main(['model', 'diagnose', '--data', str(bag), '--noise-sd', '0.25', '--out', str(diag)]) == 0
    doc = _summary(diag)
    assert doc['findings'][0]['candidate'] == 'fan_gain[HM2]', doc['summary']
    assert doc['findings'][0]['params']['gain'][0] == pytest.approx(0.7, abs=0.08)
    assert doc['data'].startswith('bag ')
    improved = tmp_path / 'improved.yaml'
    assert main(['model', 'add', '--data', str(bag), '--noise-sd', '0.25', '--from-diagnosis',
                 str(diag / 'summary.json'), '--save', str(improved), '--out', str(tmp_path / 'add')]) == 0
    assert _summary(tmp_path / 'add')['heldout_drop'] > 0.5
    loop = compare_closed_loop(setup, {'before': setup.load_model(setup.config_dir / 'reference.yaml'),
                                       'after': setup.load_model(improved)},
                               lambda s: setup.make_sim(seed=s, effects=[weak]), target='gaussian@HM2',
                               iterations=1)
    # each run starts at its prior's optimum (the warm start): the improved prior's is better,
    # and stays at least as good after the first update
    assert loop.at(0)['after'] < 0.9 * loop.at(0)['before'], loop.at(0)
    assert loop.at(1)['after'] <= 1.02 * loop.at(1)['before'], loop.at(1)


@pytest.mark.slow
def test_diagnose_on_physics_the_library_lacks_names_nothing_and_shows_the_check(tmp_path, capsys):
    # a blocked patch of the straightener: HM2's elongation patches it, but not the same in every
    # sweep; the report says so and shows the per-sweep values (the report once crashed here)
    diag = tmp_path / 'diag'
    assert main(['model', 'diagnose', '--sim', '--hidden', 'honeycomb_blockage', '--out', str(diag)]) == 0
    printed = capsys.readouterr().out
    assert 'No candidate explains the residual' in printed and 'Partly explained by' in printed
    doc = _summary(diag)
    assert doc['verdict'] == 'unexplained' and doc['findings'] == []
    refused = doc['not_reported'][0]
    assert not refused['passed'] and not refused['across_sweeps']['passed']
    assert any('does not hold across sweeps' in r for r in refused['reasons'])
    report = (diag / 'report.md').read_text()
    assert 'across sweeps (pooled' in report and 'refitted on the sweep' in report


def test_a_diagnosis_that_offered_a_term_for_the_rest_adds_it(tmp_path):
    from wind_shaper.cli.model import _diagnosis_findings
    summary = tmp_path / 'summary.json'
    doc = {'command': 'diagnose', 'findings': [{'candidate': 'swirl', 'params': {'gain': 0.4}}],
           'discrepancy': {'offered': True}, 'formula': {'offered': False}}
    summary.write_text(json.dumps(doc))
    assert _diagnosis_findings(summary) == [('swirl', {'gain': 0.4}), ('discrepancy', {})]
    doc['formula'] = {'offered': True}  # a formula, when there is one, says more than the GP
    summary.write_text(json.dumps(doc))
    assert _diagnosis_findings(summary) == [('swirl', {'gain': 0.4}), ('formula', {})]
    doc['discrepancy'] = doc['formula'] = None  # neither offered
    summary.write_text(json.dumps(doc))
    assert _diagnosis_findings(summary) == [('swirl', {'gain': 0.4})]
