"""The commissioning's field maps in a model file: written beside the fitted prior, read back
only for the key points and fans they were estimated for, and refused plainly otherwise."""
import numpy as np
import yaml

from wind_shaper.model.modelfile import (commissioning_maps_in, commissioning_maps_section,
                                         read_commissioning_maps)

KP = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]])


def _maps(n_fans=3):
    rng = np.random.default_rng(0)
    return [(rng.uniform(0, 0.65, n_fans), rng.normal(2.0, 0.5, len(KP)), rng.uniform(0.01, 0.1, len(KP)))
            for _ in range(2)]


def test_maps_come_back_for_the_key_points_and_fans_they_were_estimated_for(tmp_path):
    maps = _maps()
    path = tmp_path / 'm.yaml'
    path.write_text(yaml.safe_dump({'wind_shaper_model': 1, 'commissioning_maps':
                                    commissioning_maps_section(maps, KP)}))
    got, note = commissioning_maps_in(path, KP, 3)
    assert note == '' and len(got) == 2
    for (U, mean, std), (U2, mean2, std2) in zip(maps, got):
        np.testing.assert_allclose(U2, U, atol=1e-6)
        np.testing.assert_allclose(mean2, mean, atol=1e-4)
        np.testing.assert_allclose(std2, std, atol=1e-4)
    assert commissioning_maps_in(path.read_text(), KP, 3, text=True)[0][0][0].shape == (3,)   # the text too


def test_a_file_without_maps_has_none_and_says_nothing():
    assert read_commissioning_maps({'wind_shaper_model': 1}, KP, 3) == ([], '')


def test_maps_of_other_key_points_or_fans_or_malformed_are_not_used_and_say_why():
    section = commissioning_maps_section(_maps(), KP)
    got, note = read_commissioning_maps({'commissioning_maps': section}, KP + 0.01, 3)
    assert got == [] and 'other key points' in note and 'calibrate again' in note
    got, note = read_commissioning_maps({'commissioning_maps': section}, KP, 4)
    assert got == [] and 'map 0 has 3 commands' in note
    broken = dict(section, maps=[{'pwm': [0.1, 0.2, 0.3]}])
    assert 'lacks pwm, mean_N or std_N' in read_commissioning_maps({'commissioning_maps': broken}, KP, 3)[1]
    assert 'malformed' in read_commissioning_maps({'commissioning_maps': [1, 2]}, KP, 3)[1]
    nan = dict(section, maps=[dict(section['maps'][0], mean_N=[float('nan')] * 3)])
    assert 'not finite' in read_commissioning_maps({'commissioning_maps': nan}, KP, 3)[1]


def test_an_unreadable_file_has_no_maps_and_says_why(tmp_path):
    got, note = commissioning_maps_in(tmp_path / 'missing.yaml', KP, 3)
    assert got == [] and 'cannot be read' in note


def test_the_priors_error_is_read_from_whichever_measure_its_file_keeps(tmp_path):
    """`calibrate` keeps heldout_rmse_N, `model add --save` heldout_model_rmse_N beside the
    fit's own rmse_N; the held-out one is taken first, NaN when none is kept."""
    from wind_shaper.model.modelfile import model_error
    path = tmp_path / 'm.yaml'
    for keys, expected in [({'heldout_rmse_N': 0.3, 'rmse_N': 0.2}, 0.3),
                           ({'heldout_model_rmse_N': 0.04, 'rmse_N': 0.2}, 0.04),
                           ({'rmse_N': 0.2}, 0.2), ({}, None)]:
        path.write_text(yaml.safe_dump({'wind_shaper_model': 1, **keys}))
        got = model_error(path)
        assert (np.isnan(got) if expected is None else got == expected), (keys, got)
