"""Fixtures of the workbench tests: the shipped configuration, its commissioned reference model
(config/reference.yaml, written by `wind-shaper model fit --commission --sim --seed 100`), and
diagnostic data sets of the simulated tunnel with hidden effects switched on, each diagnosed
once per test session."""
import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.sim import make_effect
from wind_shaper.workbench.commands import simulated_sweeps
from wind_shaper.workbench.diagnose import Diagnosis

#: Seed of the diagnostic data sets (sweeps, turbulence, command design).
DATA_SEED = 5


@pytest.fixture(scope='session')
def wb_setup():
    return Setup.load()


@pytest.fixture(scope='session')
def reference(wb_setup):
    return wb_setup.load_model(wb_setup.config_dir / 'reference.yaml')


@pytest.fixture(scope='session')
def sim_data(wb_setup):
    """sim_data(*effects) -> SweepSet: 12 sweeps of 1000 samples (first and last fans off) on
    the simulated tunnel with those hidden effects (names or HiddenEffect instances)."""
    cache = {}

    def make(*effects):
        key = tuple(e if isinstance(e, str) else repr(e) for e in effects)
        if key not in cache:
            built = [make_effect(e) if isinstance(e, str) else e for e in effects]
            cache[key] = (simulated_sweeps(wb_setup.make_sim(seed=DATA_SEED, effects=built), 12,
                                           seed=DATA_SEED), built)
        return cache[key]
    return make


@pytest.fixture(scope='session')
def diagnosed(wb_setup, reference, sim_data):
    """diagnosed(*effects) -> (Diagnosis, hidden effects): the default diagnosis of the
    reference on sim_data(*effects), run once per session."""
    cache = {}

    def run(*effects):
        data, built = sim_data(*effects)
        key = tuple(e if isinstance(e, str) else repr(e) for e in effects)
        if key not in cache:
            cache[key] = Diagnosis().fit(reference, data, wb_setup.geometry)
        return cache[key], built
    return run


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
