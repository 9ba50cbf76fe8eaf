"""coordination.requests.read_model and why: a set_model request's model read from its text or
a file for a shaping run, and the words of a refusal (no rclpy)."""
import pytest

from wind_shaper.app import Setup
from wind_shaper.coordination import ShapingRun
from wind_shaper.coordination.requests import read_model, why
from wind_shaper.core.errors import ConfigError, WindShaperError
from wind_shaper.core.limits import Limits


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


@pytest.fixture
def run(setup, tmp_path):
    return ShapingRun.open(setup, tmp_path, 'r', 'parabolic')


def test_the_model_comes_from_the_text_when_there_is_one(setup, run):
    text = (setup.config_dir / 'model.yaml').read_text()
    got, source, model = read_model(run, Limits(), text, '/not/read/when/text/is/given.yaml')
    assert got == text and model is not None
    assert source == '/not/read/when/text/is/given.yaml (sent as text)'   # the path names the text
    assert read_model(run, Limits(), text, '')[1] == 'the model_yaml text'


def test_else_from_the_file(setup, run):
    path = str(setup.config_dir / 'model.yaml')
    got, source, model = read_model(run, Limits(), '  \n', path)
    assert source == path and got == (setup.config_dir / 'model.yaml').read_text()


def test_no_text_and_no_file_or_a_missing_one_is_refused(run, tmp_path):
    with pytest.raises(ConfigError, match='give a model file'):
        read_model(run, Limits(), '', '')
    with pytest.raises(ConfigError, match='cannot read .*nope.yaml'):
        read_model(run, Limits(), '', str(tmp_path / 'nope.yaml'))
    with pytest.raises(ConfigError):
        read_model(run, Limits(), 'not: a model', '')


def test_a_refusal_says_a_known_error_plainly_and_names_anything_else_shortly():
    assert why(WindShaperError('the target is unknown')) == 'the target is unknown'
    text = why(KeyError('x' * 5000))
    assert text.startswith('unexpected KeyError: ') and len(text) < 1000


def test_a_model_file_with_commissioning_maps_gives_them_to_the_run(setup, run):
    """set_model with a file that keeps the commissioning's maps: the run's first step gets
    them; a file whose maps are for other key points gives none and a warning."""
    import numpy as np
    import yaml

    from wind_shaper.model.modelfile import commissioning_maps_section
    doc = yaml.safe_load((setup.config_dir / 'model.yaml').read_text())
    kp = setup.geometry.key_points
    maps = [(np.full(7, 0.4), np.full(len(kp), 2.0), np.full(len(kp), 0.05))]
    doc['commissioning_maps'] = commissioning_maps_section(maps, kp)
    text = yaml.safe_dump(doc)
    run.set_model(text, 'the test')
    assert len(run.prior_maps) == 1 and np.allclose(run.prior_maps[0].U, 0.4)
    doc['commissioning_maps'] = commissioning_maps_section(maps, kp + 0.05)
    run.set_model(yaml.safe_dump(doc), 'the test')
    assert run.prior_maps == () and any('other key points' in t for _, t in run.notes)


def test_a_model_whose_commissioning_found_swapped_fans_is_set_with_a_warning(setup, run, tmp_path):
    """set_model with a file whose wiring check (`calibrate`) named two swapped fans: the model
    is taken (the lab decides), and the run's notes say which fans and what to do; a file whose
    check found none, or that keeps no check, adds no such note."""
    import yaml

    from wind_shaper.model.modelfile import wiring_warning
    doc = yaml.safe_load((setup.config_dir / 'model.yaml').read_text())
    doc['wiring_check'] = {'checked': True, 'swapped': ['HM1', 'LM3'], 'rmse_as_wired_N': 0.8,
                           'rmse_swapped_N': 0.3, 'why': ''}
    run.set_model(yaml.safe_dump(doc), 'the test')
    assert 'HM1 and LM3' in run.model_warning and 'channels' in run.model_warning
    assert any(kind == 'warning' and 'HM1 and LM3' in text for kind, text in run.notes)
    doc['wiring_check']['swapped'] = None
    run.set_model(yaml.safe_dump(doc), 'the test')
    assert run.model_warning == ''
    assert wiring_warning((setup.config_dir / 'model.yaml').read_text()) == ''
    assert wiring_warning('wiring_check: {swapped: [1, 2]}') == ''          # malformed: nothing said
    assert wiring_warning(': not yaml [') == ''
    # three fans moved round: the warning says which command drives which fan
    cycle = [['LM1', 'HM1'], ['HM1', 'LM2'], ['LM2', 'LM1']]
    doc['wiring_check'].update(swapped=['LM1', 'HM1', 'LM2'], drives=cycle)
    said = wiring_warning(yaml.safe_dump(doc))
    assert all(f'the command for {a} drives {b}' in said for a, b in cycle) and 'channels' in said
    doc['wiring_check']['drives'] = [['LM1', 3]]          # malformed routing: the fans are named
    assert 'LM1, HM1, LM2' in wiring_warning(yaml.safe_dump(doc))
    # a run opened again on its folder, whose model file says so, carries the note from its start
    doc['wiring_check']['swapped'] = ['LM1', 'HM1']
    run.set_model(yaml.safe_dump(doc), 'the test')
    again = ShapingRun.open(setup, tmp_path, 'r', 'parabolic')
    assert 'LM1 and HM1' in again.model_warning
    assert any(kind == 'warning' and 'LM1 and HM1' in text for kind, text in again.notes)
