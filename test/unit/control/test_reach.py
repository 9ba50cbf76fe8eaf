"""control.reach: targets the fans plainly cannot deliver are refused with the numbers."""
import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.core.errors import TargetError
from wind_shaper.control import check_reachable, model_reach


@pytest.fixture(scope='module')
def shipped():
    setup = Setup.load()
    return setup, setup.load_model()


def test_reach_is_the_model_at_the_upper_bound_for_the_paper_prior(shipped):
    setup, model = shipped
    kp, fans = setup.geometry.key_points, setup.geometry.fans
    reach = model_reach(model, kp, 0.0, 0.65, fans.enabled)
    at_max = model(np.where(fans.enabled, 0.65, 0.0), kp)
    assert reach.level == 0.65                       # thrust grows with command
    assert reach.mean_max == pytest.approx(at_max.mean()) and reach.peak_max == pytest.approx(at_max.max())


@pytest.mark.parametrize('spec', ['parabolic', 'uniform', 'gaussian', 'gaussian@HM2', 'uniform:8'])
def test_the_shipped_targets_are_within_reach(shipped, spec):
    setup, model = shipped
    setup.make_target(spec, model=model)


@pytest.mark.parametrize('spec, words', [
    ('uniform:40', 'on average'),
    ('expr:40*exp(-(x*x+y*y)/0.002)', 'at its peak'),
    ('expr:x*10', 'downward force'),
])
def test_out_of_reach_targets_are_refused_with_the_numbers(shipped, spec, words):
    setup, model = shipped
    with pytest.raises(TargetError, match=words) as info:
        setup.make_target(spec, model=model)
    assert 'N' in str(info.value) and ('u_max' in str(info.value) or '>= 0' in str(info.value))
    setup.make_target(spec)          # without a model only the spec itself is checked


def test_a_lower_u_max_shrinks_the_reach(shipped):
    setup, model = shipped
    kp, fans = setup.geometry.key_points, setup.geometry.fans
    values = np.full(len(kp), 6.0)
    check_reachable(values, kp, model, 0.0, 0.65, fans.enabled)
    with pytest.raises(TargetError, match='u_max = 0.3'):
        check_reachable(values, kp, model, 0.0, 0.3, fans.enabled)
