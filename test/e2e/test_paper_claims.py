"""The paper's claims, reproduced on the simulated tunnel with the shipped config and model.

For each target the loop starts at U_0 = 0.5 and runs Algorithm 1 exactly (lambda_k = 0.8/(k+1),
pseudo-inverse of the prior's Jacobian, clipping to [0, 0.65]); errors are scored on the
simulator's noise-free field at the 317 key points.
"""
import numpy as np
import pytest

from wind_shaper.app import Setup, shape_on_sim

PAPER = {'method': 'paper'}  # the paper's claims are about Algorithm 1, whatever the default is

CASES = [
    ('uniform', ()),
    ('gaussian@LM1', ()),
    ('parabolic', ()),
    ('uniform', ('CM',)),
    ('gaussian@LM1', ('CM',)),
]


@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('target,disabled', CASES, ids=[f'{t}-off:{",".join(d) or "none"}' for t, d in CASES])
def test_error_after_six_iterations_is_at_most_half_of_iteration_zero(target, disabled, seed):
    setup = Setup.load(disabled=disabled)
    records, _ = shape_on_sim(setup, target, iterations=6, seed=seed, u0=0.5, rule_overrides=PAPER)
    assert [r.k for r in records] == list(range(7))
    assert records[6].true_error <= 0.5 * records[0].true_error
    # the GP estimate tracks the truth it is scored against
    assert abs(np.sqrt(records[6].error) - np.sqrt(records[6].true_error)) < 0.1
    for name in disabled:
        j = setup.geometry.fans.index(name)
        assert all(r.pwm[j] == 0.0 for r in records)
    assert all(np.all((r.pwm >= 0.0) & (r.pwm <= setup.shaping.u_max)) for r in records)


@pytest.mark.parametrize('seed', [0, 1])
def test_parabolic_profile_drives_the_central_fan_to_zero(seed):
    setup = Setup.load()
    cm = setup.geometry.fans.index('CM')
    records, _ = shape_on_sim(setup, 'parabolic', iterations=12, seed=seed, u0=0.5, rule_overrides=PAPER)
    # to zero, or to within a hair of it: a step of the paper's shrinking schedule can leave the
    # fan a fraction of a percent above its clip (0.15 % in one seed; it starts at 50 %), where
    # no ESC turns a propeller
    assert records[-1].pwm[cm] <= 0.005
    edge = np.delete(records[-1].pwm, cm)
    assert np.all(edge > 0.4)  # the edge fans carry the ring of the parabola


def test_gaussian_over_a_lower_fan_ends_with_that_fan_highest():
    setup = Setup.load()
    records, _ = shape_on_sim(setup, 'gaussian@LM1', iterations=12, u0=0.5, rule_overrides=PAPER)
    edge = [setup.geometry.fans.index(n) for n in ('LM1', 'HM1', 'LM2', 'HM2', 'LM3', 'HM3')]
    final = records[-1].pwm
    assert int(np.argmax(final[edge])) == 0


def test_error_plateaus_above_zero_because_the_rig_is_under_actuated():
    setup = Setup.load()
    records, _ = shape_on_sim(setup, 'parabolic', iterations=12, u0=0.5, rule_overrides=PAPER)
    e = np.array([r.true_error for r in records])
    assert e[12] > 0.05 * e[0]          # 7 fans cannot match 317 points exactly
    assert e[12] >= 0.7 * e[7]          # and little changes after 6-7 iterations
