"""workbench.suggest: the next sweeps the diagnosis proposes: within the bounds, spread, aimed at
what separates the hypotheses or pins the parameters down."""
import numpy as np
import pytest

from wind_shaper.experiment import make_design
from wind_shaper.model import FanGain
from wind_shaper.workbench.suggest import information_gain, separation, suggest_sweeps


def test_two_hypotheses_about_one_fan_are_separated_by_running_that_fan_high(wb_setup, reference):
    fans = wb_setup.geometry.fans
    j = fans.names.index('HM2')
    weaker = FanGain(fans, reference, fan=['HM2'], gain=0.8)
    rng = np.random.default_rng(0)
    U = rng.uniform(0.0, 0.65, (300, fans.n_fans))
    S = separation([reference, weaker], U, wb_setup.geometry.key_points, 0.05)[:, 0]
    assert U[np.argmax(S), j] > 0.55
    off = U.copy()
    off[:, j] = 0.0   # only the thrust polynomial's constant term is left to tell them apart
    assert np.max(separation([reference, weaker], off, wb_setup.geometry.key_points, 0.05)) < 0.05 * S.max()


def test_a_fan_that_is_off_teaches_next_to_nothing_about_its_gain(wb_setup, reference):
    fans = wb_setup.geometry.fans
    model = FanGain(fans, reference, fan=['LM1'], gain=1.1)
    mask = np.zeros(len(model.theta), bool)
    mask[model.theta_names.index('fan_gain[LM1].gain')] = True
    U = np.full((2, fans.n_fans), 0.4)
    U[1, fans.names.index('LM1')] = 0.0
    G = information_gain(model, mask, U, wb_setup.geometry.key_points, 0.05)
    # only the thrust polynomial's constant term is left to show the gain
    assert G[0, 0, 0] > 0 and G[1, 0, 0] < 0.01 * G[0, 0, 0]


@pytest.mark.parametrize('goal', ['separate', 'shrink'])
def test_suggested_sweeps_are_a_checked_spread_design_that_collect_reads(diagnosed, wb_setup, goal, tmp_path):
    d, _ = diagnosed('tilted_fan')
    s = suggest_sweeps(d, 4, 0.0, 0.65, goal=goal, seed=1)
    U = s.design.commands
    assert s.goal == goal and U.shape == (4, wb_setup.geometry.fans.n_fans)
    assert np.all((U == 0) | ((U >= 0.0) & (U <= 0.65)))
    gaps = [np.max(np.abs(U[a] - U[b])) for a in range(4) for b in range(a + 1, 4)]
    assert min(gaps) >= 0.1 * 0.65
    if goal == 'separate':
        assert s.hypotheses[0] == 'no further effect' and len(s.hypotheses) >= 2
        assert s.value_after['min_separation'] > s.value_before['min_separation']
    else:  # every fitted parameter's predicted error shrinks, none grows
        ratio = np.array([s.value_after[k] / s.value_before[k] for k in s.value_before])
        assert np.all(ratio <= 1 + 1e-9) and np.median(ratio) < 0.95
    assert 'expected' in s.summary()['expected'] or s.outcome_text()
    from wind_shaper.experiment import write_design
    path = write_design(tmp_path / 'next.csv', s.design)
    again = make_design(str(path), wb_setup.geometry.fans, 0.0, 0.65)
    assert np.allclose(again.commands, U)


def test_a_disabled_fan_is_never_suggested_on():
    from wind_shaper.app import Setup
    from wind_shaper.workbench.commands import simulated_sweeps
    from wind_shaper.workbench.diagnose import Diagnosis
    setup = Setup.load(disabled=['CM'])
    reference = setup.load_model(setup.config_dir / 'reference.yaml')
    data = simulated_sweeps(setup.make_sim(seed=3), 6, seed=3)
    d = Diagnosis(max_effects=1).fit(reference, data, setup.geometry)
    s = suggest_sweeps(d, 3, 0.0, 0.65, goal='shrink')
    assert np.all(s.design.commands[:, setup.geometry.fans.names.index('CM')] == 0.0)
