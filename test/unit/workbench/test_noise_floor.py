"""The noise floor: a held-out residual the noise explains is not described, sizes stay inside the
tunnel, and no error is printed below the noise."""
import re

import numpy as np
import pytest
from scipy.signal import lfilter

from wind_shaper.workbench.discrepancy import DiscrepancyFit, describe_map, disc_grid, outside_text
from wind_shaper.workbench.noise_floor import effective_samples, noise_floor_test
from wind_shaper.workbench.wording import error_text


def turbulence(rng, n_sweeps=4, n=1000, sd=0.17, phi=0.82):
    """Noise like the simulator's: half white, half AR(1) with lag-1 correlation ``phi``, per
    sweep; (residual, sweep index)."""
    parts = []
    for _ in range(n_sweeps):
        white = rng.standard_normal(n)
        ar = lfilter([np.sqrt(1 - phi ** 2)], [1, -phi], rng.standard_normal(n))
        parts.append(sd * np.sqrt(0.5) * (white + ar))
    return np.concatenate(parts), np.repeat(np.arange(n_sweeps), n)


def test_noise_alone_is_within_the_floor_at_its_stated_level():
    rng = np.random.default_rng(3)
    within = [noise_floor_test(*turbulence(rng), 0.17).within for _ in range(40)]
    assert sum(within) >= 34  # 95 % nominal; 40 draws


def test_correlated_noise_counts_fewer_independent_samples():
    rng = np.random.default_rng(4)
    r, sweep = turbulence(rng, phi=0.97)
    n_eff = effective_samples(r, sweep, 0.17 ** 2)
    assert n_eff < 0.5 * len(r)
    white = rng.standard_normal(4000) * 0.17
    assert effective_samples(white, sweep, 0.17 ** 2) > 0.9 * len(white)


def test_a_model_error_well_above_the_noise_is_not_within_the_floor():
    rng = np.random.default_rng(5)
    r, sweep = turbulence(rng)
    t = np.arange(len(r))
    pattern = 0.5 * 0.17 * np.sqrt(2) * np.sin(2 * np.pi * t / 400)  # smooth along the path
    test = noise_floor_test(r + pattern, sweep, 0.17)
    assert not test.within and test.ratio > 1.15
    assert 'above the 95 % bound' in test.text()
    # an estimated noise (its own uncertainty) widens the bound
    loose = noise_floor_test(r, sweep, 0.17, resolution=0.05)
    assert loose.bound > noise_floor_test(r, sweep, 0.17).bound and 'F(' in loose.law()


def test_no_error_is_printed_as_zero_below_the_noise():
    assert error_text(0.0, 0.03) == 'at the noise level (below 0.030 N)'
    assert error_text(0.02, 0.03).startswith('at the noise level')
    assert error_text(0.0) == 'at the noise level'
    assert error_text(0.062, 0.03) == '0.062 N'
    fit = DiscrepancyFit(term=None, log_evidence=0.0, noise_sd=0.05, shares={}, words=['It is flat.'],
                         heldout_before=0.06, heldout_after=0.0, error_floor=0.02, sample_noise=0.08,
                         below_noise=True)
    text = outside_text(fit)
    assert 'from 0.060 N to the noise level (below 0.020 N)' in text and text.startswith('Below the noise')


def test_no_patch_is_described_larger_than_the_tunnel(wb_setup):
    geo = wb_setup.geometry
    grid = disc_grid(geo.sweep_radius, 0.02)
    x, y = grid.T
    # two patches at opposite edges: their weighted spread, read as one region, spans more than
    # the tunnel's 80 cm (a "strip 134 cm long" before sizes were held to the tunnel)
    two = (np.hypot(x - 0.3, y - 0.3) < 0.1) * 1.0 + (np.hypot(x + 0.3, y + 0.3) < 0.1) * 1.0 - 0.05
    text = describe_map(two, grid, geo)
    sizes = [float(s) for s in re.findall(r'(\d+) cm', text)]
    assert sizes and max(sizes) <= 200 * geo.wall_radius, text
    assert 'most of the tunnel' in text


@pytest.mark.slow
def test_clean_sweeps_describe_nothing_and_say_so(diagnosed):
    d, _ = diagnosed()
    assert d.verdict_ == 'explained' and d.discrepancy_ is None
    assert 'to the noise level' in d.summary() and '0.000 N' not in d.summary()
    floor = d.to_json()['noise_floor']
    assert floor['n_eff'] < floor['n'] and floor['bound'] > 1


def test_the_noise_estimates_stated_uncertainty_matches_its_scatter_on_dense_gusty_sweeps():
    """The noise variance from revisits: on sweeps sampled at 100 Hz with gusts that last
    several samples (as a force stream averaged over 10 ms gives), the standard error it
    states (``resolution``, which sets the F-test's bound) is about its actual scatter over
    repeated sweeps; counting every pair as independent stated a sixth of it, and the test
    then called the model error of clean data material."""
    from wind_shaper.core.tunnel import Sweep
    from wind_shaper.workbench.data import SweepSet
    from wind_shaper.workbench.metrics import HeldOut
    rng = np.random.default_rng(0)
    t = np.arange(0, 20.0, 0.01)
    path = np.c_[0.25 * np.sin(2 * np.pi * t / 4.0), 0.25 * np.sin(2 * np.pi * t / 9.7)]   # revisits

    def gusty():
        ar = lfilter([np.sqrt(1 - 0.86 ** 2)], [1, -0.86], rng.standard_normal(len(t)))
        return 0.09 * (np.sqrt(0.3) * rng.standard_normal(len(t)) + np.sqrt(0.7) * ar)
    flat = lambda U, Z: np.full(len(Z), 2.0)   # noqa: E731 - the field is known exactly
    variances, stated = [], []
    for _ in range(40):
        held = HeldOut(SweepSet([Sweep(path, 2.0 + gusty(), t, np.full(7, 0.5)) for _ in range(2)],
                                tuple(f'f{i}' for i in range(7))))
        sd = held.estimate_noise(flat)
        variances.append(sd ** 2)
        stated.append(held.resolution ** 2 / 2 / sd ** 2)    # relative standard error
    actual = np.std(variances) / np.mean(variances)
    assert 0.6 < np.mean(stated) / actual < 1.5, (np.mean(stated), actual)
    assert abs(np.sqrt(np.mean(variances)) - 0.09) < 0.01
