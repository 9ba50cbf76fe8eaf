"""A finding's error bar covers the truth: the fit's own standard error, the whole-model
jackknife over sweeps and the model-form spread (``workbench.uncertainty``). A wall layer is
read about 15 % thin (the refitted jets take part of its deficit): the fit's own sigma and a
jackknife of the layer's thickness alone are a tenth of that miss."""
import numpy as np
import pytest

from wind_shaper.workbench.library import candidate_for_hidden_effect


@pytest.mark.slow
@pytest.mark.parametrize('effect', ['wall_boundary_layer', 'weak_fan'])
def test_the_reported_error_bar_covers_the_truth(effect, diagnosed):
    d, (hidden,) = diagnosed(effect)
    name, truth = candidate_for_hidden_effect(hidden)
    (t,) = [t for t in d.steps_ if t.candidate.name == name]
    for key, true in truth.items():
        value = np.ravel(np.asarray(t.params[key], float))
        sigma = np.ravel(np.asarray(t.std[key], float))
        assert np.all(np.abs(value - np.ravel(true)) <= 2 * sigma), (key, value, sigma, true)
        # the selection's own error bar is kept, and the reported one is never narrower
        assert np.all(sigma >= np.ravel(t.selection_std[key]) - 1e-12)
    # the finding's words carry the wider error bar
    if effect == 'wall_boundary_layer':
        assert f'± {100 * t.std["thickness"][0]:.1f}' in t.finding
