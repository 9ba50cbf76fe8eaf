"""The simulator's optional noise kinds: off by default (the default draws are unchanged), and
each does what its name says."""
import numpy as np
import pytest

from wind_shaper.core.errors import ConfigError
from wind_shaper.sim import NoiseModel

DT = 0.02


def _draws(model, n=20000, seed=0, force=2.5):
    return model.forces(np.full(n, force), DT, np.random.default_rng(seed)) - force


def _autocorr(x, lag):
    x = x - x.mean()
    return float(np.mean(x[:-lag] * x[lag:]) / np.var(x))


def test_the_default_draws_are_the_documented_formula():
    rng = np.random.default_rng(3)
    m = NoiseModel()
    xi_m = m.unit_series(1000, DT, rng)[:, 0]
    xi_a = m.unit_series(1000, DT, rng)[:, 0]
    F = np.linspace(1, 4, 1000)
    np.testing.assert_array_equal(m.forces(F, DT, np.random.default_rng(3)),
                                  F * (1 + m.relative * xi_m) + m.absolute * xi_a)


def test_student_t_tails_are_heavy_with_the_same_variance():
    base = NoiseModel(correlated_fraction=0.0, absolute=0.0)
    heavy = NoiseModel(correlated_fraction=0.0, absolute=0.0, tails=3.0)
    a, b = _draws(base, 200000), _draws(heavy, 200000)
    assert np.std(b) == pytest.approx(np.std(a), rel=0.1)
    kurt = lambda x: np.mean(x ** 4) / np.mean(x ** 2) ** 2
    assert kurt(a) == pytest.approx(3.0, abs=0.2) and kurt(b) > 6.0


def test_two_scale_gusts_last_longer():
    one = NoiseModel(correlated_fraction=1.0, absolute=0.0)
    two = NoiseModel(correlated_fraction=1.0, absolute=0.0, gusts='two_scale', slow_time=1.0)
    lag = int(0.5 / DT)   # 0.5 s: five 0.1 s correlation times
    assert _autocorr(_draws(one), lag) < 0.05
    assert _autocorr(_draws(two), lag) > 0.2
    assert np.std(_draws(two)) == pytest.approx(np.std(_draws(one)), rel=0.15)


def test_von_karman_gusts_have_no_single_correlation_time():
    one = NoiseModel(correlated_fraction=1.0, absolute=0.0)
    broad = NoiseModel(correlated_fraction=1.0, absolute=0.0, gusts='von_karman', slow_time=0.5)
    x = np.concatenate([_draws(broad, seed=s) for s in range(4)])
    assert np.std(x) == pytest.approx(np.std(_draws(one)), rel=0.1)
    short, long = _autocorr(x, int(0.1 / DT)), _autocorr(x, int(1.0 / DT))
    # an exponential kernel would give short ** 10 at ten times the lag; the spectrum's
    # large eddies keep far more, its -5/3 range takes more at short lags than one time scale
    assert 0.5 < short < 0.9 and long > 2.0 * short ** 10


def test_the_exponent_makes_the_turbulence_grow_faster_than_the_force():
    m = NoiseModel(absolute=0.0, exponent=1.5, force_ref=2.5)
    low, high = np.std(_draws(m, force=1.0)), np.std(_draws(m, force=4.0))
    assert high / low == pytest.approx(4.0 ** 1.5, rel=0.1)
    assert m.sd(np.array([4.0]))[0] == pytest.approx(0.04 * 2.5 * (4.0 / 2.5) ** 1.5)


def test_drift_walks_away():
    m = NoiseModel(relative=0.0, absolute=0.0, drift=0.05)
    ends = [_draws(m, n=1000, seed=s)[-1] for s in range(300)]   # 20 s sweeps at 50 Hz
    assert np.std(ends) == pytest.approx(0.05, rel=0.2)


@pytest.mark.parametrize('cfg,match', [({'gusts': 'pink'}, 'gusts'), ({'tails': 1.5}, 'tails'),
                                       ({'exponent': 0}, 'exponent'), ({'drift': -1}, 'drift'),
                                       ({'wind': 1}, 'keys are')])
def test_bad_noise_settings_are_refused(cfg, match):
    with pytest.raises(ConfigError, match=match):
        NoiseModel.from_config(cfg)
