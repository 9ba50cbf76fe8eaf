"""The `wind-shaper` command as a user runs it: prints iterations, writes the report folder."""
import json
import subprocess
import sys

import pytest

from wind_shaper.cli.main import main


def test_shape_writes_report_and_json(tmp_path, capsys):
    out = tmp_path / 'report'
    rc = main(['shape', '--sim', '--target', 'uniform', '--iterations', '3', '--out', str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert printed.count('k=') == 4 and 'true-field RMSE' in printed
    doc = json.loads((out / 'run.json').read_text())
    assert [it['k'] for it in doc['iterations']] == [0, 1, 2, 3]
    assert len(doc['key_points_m']) == 317 and doc['fans'][-1] == 'CM'
    first, last = doc['iterations'][0], doc['iterations'][-1]
    assert last['true_rmse_N'] < first['true_rmse_N']
    assert first['next_pwm'] is not None and last['next_pwm'] is None
    for png in ('field_maps.png', 'error.png', 'pwm.png'):
        data = (out / png).read_bytes()
        assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 10_000
    assert (out / 'sweeps.npz').stat().st_size > 10_000


@pytest.mark.parametrize('argv,message', [
    (['shape', '--sim', '--target', "expr:__import__('os').system('true')"], 'not allowed'),
    (['shape', '--sim', '--target', 'gaussian@NOPE'], 'NOPE'),
    (['shape', '--sim', '--disable', 'XX'], 'XX'),
    (['shape', '--target', 'uniform'], '--sim'),
])
def test_bad_input_gets_a_clear_error_and_exit_2(argv, message, capsys, tmp_path):
    assert main(argv + ['--out', str(tmp_path / 'r')]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'r').exists()  # nothing half-written


def test_console_script_is_installed_and_runs(tmp_path):
    exe = [sys.executable, '-m', 'wind_shaper.cli.main']
    done = subprocess.run(exe + ['shape', '--sim', '--target', 'parabolic', '--iterations', '1',
                                 '--out', str(tmp_path / 'r')], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert 'report:' in done.stdout


def test_calibrate_refits_the_shipped_model(tmp_path):
    from wind_shaper.app import Setup
    out = tmp_path / 'model.yaml'
    assert main(['calibrate', '--sim', '--out', str(out)]) == 0
    setup = Setup.load()
    fresh, shipped = setup.load_model(out), setup.load_model()
    import numpy as np
    U = np.full(7, 0.5)
    kp = setup.geometry.key_points
    # the shipped config/model.yaml is what calibration on the default simulator produces
    np.testing.assert_allclose(fresh(U, kp), shipped(U, kp), atol=0.02)


def test_calibrate_on_the_simulator_from_designed_sweeps(tmp_path, capsys):
    """`calibrate --sim --design lhs:6` commissions as the guide says, in-process: six sweeps with
    every fan running between two with the fans off, the prior fitted and graded on held-out ones."""
    import yaml
    out = tmp_path / 'prior.yaml'
    assert main(['calibrate', '--sim', '--design', 'lhs:6', '--out', str(out)]) == 0
    saved = yaml.safe_load(out.read_text())
    assert saved['fitted_from'].startswith('6 moving-plate sweeps') and 'lhs:6' in saved['fitted_from']
    assert 0 < saved['heldout_rmse_N'] < 1.0
    said = capsys.readouterr().out
    assert 'held-out sweeps' in said and '4 of the sweeps kept as field maps' in said
    # the four sweeps with fans running, as field maps at the key points, for a run's first step
    from wind_shaper.app import Setup
    setup = Setup.load()
    assert len(saved['commissioning_maps']['maps']) == 4
    maps, note = setup.prior_maps(out)
    assert note == '' and len(maps) == 4 and maps[0].mean.shape == (len(setup.geometry.key_points),)


@pytest.mark.parametrize('argv,said', [
    (['--sim', '--design', 'lhs:2'], 'lhs:N with N >= 3'),
    (['--data', 'runs/x', '--design', 'lhs:6'], '--design goes with --sim')])
def test_calibrate_refuses_a_design_it_cannot_run(argv, said, tmp_path, capsys):
    assert main(['calibrate', *argv, '--out', str(tmp_path / 'p.yaml')]) == 2
    assert said in capsys.readouterr().err
    assert not (tmp_path / 'p.yaml').exists()


def _true_rmse(out):
    return [it['true_rmse_N'] for it in json.loads((out / 'run.json').read_text())['iterations']]


def test_shape_hidden_switches_on_a_simulator_effect(tmp_path, capsys):
    """`shape --sim --hidden` shapes the tunnel with the effect (as `model diagnose --sim --hidden`)."""
    plain, weak = tmp_path / 'plain', tmp_path / 'weak'
    assert main(['shape', '--sim', '--target', 'gaussian@HM2', '--iterations', '1', '--out', str(plain)]) == 0
    assert main(['shape', '--sim', '--target', 'gaussian@HM2', '--iterations', '1', '--out', str(weak),
                 '--hidden', 'weak_fan:fan=HM2,gain=0.8']) == 0
    assert 'hidden effects: weak_fan:fan=HM2,gain=0.8' in capsys.readouterr().out
    doc = json.loads((weak / 'run.json').read_text())
    assert doc['hidden_effects'] == [{'name': 'weak_fan', 'fan': 'HM2', 'gain': 0.8}]
    # same seed and commands at k=0, another tunnel: HM2 at 80 % changes the true field
    assert abs(_true_rmse(weak)[0] - _true_rmse(plain)[0]) > 0.05
    assert main(['shape', '--sim', '--hidden', 'weak_fan:fan=NOPE', '--out', str(tmp_path / 'r')]) == 2
    assert 'NOPE' in capsys.readouterr().err and not (tmp_path / 'r').exists()



def test_shape_biases_the_sensor_before_every_sweep_when_asked(tmp_path):
    """`shape --sim --bias-zero every_sweep` on a drifting sensor zero: every sweep's map starts
    from a zeroed sensor, so the estimate stays near the true field, at a spin-down more per
    sweep in the tunnel time."""
    drift = ['--hidden', 'sensor_zero_drift:rate=0.01']
    runs = {}
    for mode in ('never', 'every_sweep'):
        out = tmp_path / mode
        assert main(['shape', '--sim', '--target', 'uniform', '--iterations', '2', '--out', str(out),
                     '--bias-zero', mode, *drift]) == 0
        runs[mode] = json.loads((out / 'run.json').read_text())
    gap = {m: [abs(it['rmse_N'] - it['true_rmse_N']) for it in doc['iterations']] for m, doc in runs.items()}
    # unbiased, the zero has grown by the last sweep (some 0.3 N after 30 s of plate time)
    assert gap['never'][-1] > 0.1 and gap['every_sweep'][-1] < 0.5 * gap['never'][-1], gap
    settle = {m: doc['tunnel_time_s']['settle_s'] for m, doc in runs.items()}
    assert settle['every_sweep'] == [2 * settle['never'][0]] * 3, settle   # fans off, then on

PLUGIN = '''
import numpy as np
from wind_shaper.model import Hyper, Term, register_term

@register_term
class Updraft(Term):
    kind = {kind!r}
    hypers = (Hyper('force', 1, (-1.0, 3.0)),)

    def __init__(self, fans, force=0.0, fixed=()):
        self.fans = fans
        self.force = float(force)
        self._init_hypers(fixed)
        self._check_bounds()

    def _value_and_grad(self, U, Z, jacobian):
        return np.full(len(Z), self.force), (np.zeros_like(U) if jacobian else None)
'''


def _plugin_model(tmp_path, name):
    """A plugin file with a term kind of its own and a model file naming that kind."""
    import uuid

    import yaml

    from wind_shaper.app import Setup
    kind = f'updraft_{uuid.uuid4().hex[:8]}'
    plugin = tmp_path / f'{name}.py'
    plugin.write_text(PLUGIN.format(kind=kind))
    doc = yaml.safe_load(Setup.load().model_path.read_text())
    doc['model'] = {'kind': 'sum', 'terms': [doc['model'], {'kind': kind, 'force': 0.1}]}
    model = tmp_path / f'{name}.yaml'
    model.write_text(yaml.safe_dump(doc))
    return plugin, model


def test_shape_loads_a_model_naming_a_term_of_your_own(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv('WIND_SHAPER_PLUGINS', raising=False)
    plugin, model = _plugin_model(tmp_path, 'by_option')
    argv = ['shape', '--sim', '--target', 'uniform', '--iterations', '1', '--model', str(model)]
    assert main(argv + ['--out', str(tmp_path / 'r0')]) == 2
    assert '--plugin FILE or WIND_SHAPER_PLUGINS' in capsys.readouterr().err
    assert main(argv + ['--plugin', str(plugin), '--out', str(tmp_path / 'r1')]) == 0
    plugin, model = _plugin_model(tmp_path, 'by_env')
    monkeypatch.setenv('WIND_SHAPER_PLUGINS', str(plugin))
    assert main(['shape', '--sim', '--target', 'uniform', '--iterations', '1', '--model', str(model),
                 '--out', str(tmp_path / 'r2')]) == 0
    assert 'Updraft' in json.loads((tmp_path / 'r2' / 'run.json').read_text())['model']
    # the warm start's check reads the prior's error from the file given, as from the config's own
    assert 'not judged' not in capsys.readouterr().out


def test_help_names_the_default_update_rule(capsys):
    with pytest.raises(SystemExit):
        main(['--help'])
    out = ' '.join(capsys.readouterr().out.split())
    assert 'adaptive by default' in out and 'run the online-learning loop (Algorithm 1)' not in out
