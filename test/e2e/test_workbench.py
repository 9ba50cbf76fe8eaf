"""The model workbench as a user drives it: `wind-shaper model ...` on the simulated tunnel, and
the whole way through a bag (record sweeps, diagnose from the bag, add the effect, rerun)."""
import json

import pytest

from wind_shaper.cli.main import main


def _summary(out):
    return json.loads((out / 'summary.json').read_text())


@pytest.mark.slow
def test_diagnose_then_add_on_the_simulator(tmp_path, capsys):
    hidden = ['--sim', '--hidden', 'tilted_fan:fan=LM2,shift=0.04/0', '--seed', '5']
    diag = tmp_path / 'diag'
    assert main(['model', 'diagnose', *hidden, '--out', str(diag)]) == 0
    printed = capsys.readouterr().out
    assert 'the jet of fan LM2 lands' in printed and 'report:' in printed
    doc = _summary(diag)
    assert doc['verdict'] == 'found' and doc['findings'][0]['candidate'] == 'fan_shift[LM2]'
    assert doc['truth'] == [{'name': 'tilted_fan', 'fan': 'LM2', 'shift': [0.04, 0.0]}]
    html = (diag / 'report.html').read_text()
    assert html.count('data:image/png;base64,') >= 4 and 'Against the simulator' in html
    for png in ('diagnosis_maps.png', 'diagnosis_fans.png', 'diagnosis_radial.png', 'ranking_step1.png'):
        assert (diag / png).read_bytes()[:4] == b'\x89PNG'

    add, model = tmp_path / 'add', tmp_path / 'improved.yaml'
    assert main(['model', 'add', *hidden, '--from-diagnosis', str(diag / 'summary.json'),
                 '--save', str(model), '--closed-loop', 'gaussian@LM2', '--rule', 'paper',
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
    assert set(doc['train_overall']) >= {'rmse', 'r2', 'max_error'} and doc['train_overall']['r2'] > 0.99
    assert all('std' in p for p in doc['fit']['parameters'].values())
    cmp = tmp_path / 'cmp'
    assert main(['model', 'compare', '--sim', '--sweeps', '6', '--model', 'config/model.yaml',
                 '--model', str(tmp_path / 'fitted.yaml'), '--out', str(cmp)]) == 0
    models = _summary(cmp)['models']
    assert models['fitted']['heldout_model_rmse_N'] < models['model']['heldout_model_rmse_N']
    assert 'held-out model error' in capsys.readouterr().out


@pytest.mark.parametrize('argv,message', [
    (['model', 'diagnose'], '--sim'),
    (['model', 'diagnose', '--sim', '--hidden', 'warp_drive'], 'warp_drive'),
    (['model', 'add', '--sim', '--effect', 'fan_gain[NOPE]'], 'fan_gain[NOPE]'),
    (['model', 'diagnose', '--data', 'no/such/bag'], 'does not exist'),
    (['model', 'add', '--sim'], 'nothing to add'),
])
def test_bad_input_is_named(argv, message, capsys, tmp_path):
    assert main(argv + ['--sweeps', '3', '--samples', '60', '--out', str(tmp_path / 'o')]) == 2
    assert message in capsys.readouterr().err


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
                               iterations=6, rule_overrides={'method': 'paper'})
    assert loop.at(6)['after'] < loop.at(6)['before']
