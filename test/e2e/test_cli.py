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
