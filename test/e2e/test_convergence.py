"""The shipped default (warm start, adaptive update, sweeps as long as needed) reaches the best
field the fans can make, fast.

zeta* is the lowest true-field error [N^2] over the bounded PWMs, found by optimising the
simulator's noise-free field directly. bench/convergence.py measured the default at iteration 4
within 1.10 zeta* in every run of these cases (median 1.00-1.02, 5 seeds); the paper's Algorithm 1
is at 2-17 zeta* there. The bound below, 1.15 zeta* for every run, leaves a margin for noise.
"""
import numpy as np
import pytest
from scipy.optimize import least_squares

from wind_shaper.app import Setup, shape_on_sim
from wind_shaper.control import AdaptiveUpdate

WITHIN = 1.15


def zeta_star(setup, target_values, sim, starts):
    kp = setup.geometry.key_points
    lo, hi = setup.shaping.u_min, setup.shaping.u_max
    best = np.inf
    for u0 in starts:
        sol = least_squares(lambda u: sim.true_field(u, kp) - target_values, np.clip(u0, lo, hi),
                            bounds=(lo, hi), diff_step=1e-4, xtol=1e-10, ftol=1e-10)
        best = min(best, float(np.mean(sol.fun ** 2)))
    return best


@pytest.mark.slow
@pytest.mark.parametrize('target', ['uniform', 'gaussian@LM1', 'parabolic'])
def test_default_update_is_within_15_percent_of_the_optimum_by_iteration_4(target):
    setup = Setup.load()
    assert isinstance(setup.shaping.make_rule(), AdaptiveUpdate)  # the shipped default
    kp = setup.geometry.key_points
    tv = setup.make_target(target).values(kp)
    finals, errors = [], []
    for seed in (0, 1, 2):
        records, _ = shape_on_sim(setup, target, iterations=4, seed=seed)
        errors.append([r.true_error for r in records])
        finals.append(records[-1].pwm)
        assert all(np.all((r.pwm >= 0) & (r.pwm <= setup.shaping.u_max)) for r in records)
    sim = setup.make_sim(seed=0)
    zs = zeta_star(setup, tv, sim, [np.full(7, 0.5)] + finals)
    ratios = np.array(errors) / zs
    assert np.all(ratios[:, 4] <= WITHIN), ratios[:, 4]
    # and the paper's protocol (Algorithm 1 from every fan at 0.5), same seeds, is far from it
    paper, _ = shape_on_sim(setup, target, iterations=4, seed=0, u0=0.5, rule_overrides={'method': 'paper'})
    assert paper[4].true_error > ratios[0, 4] * zs
