"""Calibration fit on synthetic data, model files, and the loop on a plant that is a model."""
import numpy as np
import pytest

from wind_shaper.model.calibration import CalibrationPlan, collect_calibration, fit_model
from wind_shaper.core.errors import ModelFileError
from wind_shaper.estimation.field import FieldEstimator
from wind_shaper.control import CommandBounds, PaperUpdate, ShapingLoop, mean_squared_error
from wind_shaper.model import CentralRing, FanJets, paper_prior
from wind_shaper.model.modelfile import load_model, save_model
from wind_shaper.core.tunnel import Sweep, Tunnel

TRUE_JETS = dict(thrust_higher=(0.05, 2.4, 11.0), thrust_lower=(0.02, 2.0, 9.0), sigma=0.16)
TRUE_RING = dict(thrust=(0.0, 1.5, 8.0), offset=0.3, sigma=0.3)


class ModelPlant:
    """A test tunnel whose true field is a model term plus white noise (not the simulator)."""

    def __init__(self, geometry, term, noise=0.02, seed=0):
        self.geometry, self.term, self.noise = geometry, term, noise
        self.rng = np.random.default_rng(seed)
        self.U = np.zeros(geometry.fans.n_fans)

    def apply(self, pwm):
        self.U = np.where(self.geometry.fans.enabled, np.clip(pwm, 0, 1), 0.0)
        return self.U.copy()

    def sweep(self, n_samples=1000):
        r = self.geometry.sweep_radius * np.sqrt(self.rng.uniform(0, 1, n_samples))
        a = self.rng.uniform(0, 2 * np.pi, n_samples)
        P = np.column_stack([r * np.cos(a), r * np.sin(a)])
        F = self.term(self.U, P) + self.noise * self.rng.standard_normal(n_samples)
        return Sweep(P, F, np.arange(n_samples) / 50.0, self.U.copy())

    def measure_at(self, positions, samples_per_point=20):
        positions = np.asarray(positions, float).reshape(-1, 2)
        noise = self.noise / np.sqrt(samples_per_point)
        return self.term(self.U, positions) + noise * self.rng.standard_normal(len(positions))


@pytest.fixture
def plant(rig):
    return ModelPlant(rig, FanJets(rig.fans, **TRUE_JETS) + CentralRing(rig.fans, **TRUE_RING))


def test_model_plant_is_a_tunnel(plant):
    assert isinstance(plant, Tunnel)


def test_calibration_batch_is_the_papers_plan(plant, rig):
    data = collect_calibration(plant, CalibrationPlan())
    levels = 17  # 0 .. 80 % in 5 % steps
    assert len(data) == 7 * (levels + 16)
    assert np.isclose(data.pwm.max(), 0.8)
    # one fan at a time
    assert np.all((data.pwm > 0).sum(axis=1) <= 1)


def test_fit_recovers_the_true_parameters(plant, rig):
    data = collect_calibration(plant, CalibrationPlan())
    fit = fit_model(paper_prior(rig.fans), data)
    params = dict(zip(fit.names, fit.theta))
    assert params['k1__sigma'] == pytest.approx(0.16, rel=0.03)
    assert params['k1__thrust_higher[2]'] == pytest.approx(11.0, rel=0.08)
    assert params['k1__thrust_lower[2]'] == pytest.approx(9.0, rel=0.08)
    assert fit.rmse < 0.02
    assert np.all(fit.theta_std > 0) and np.all(np.isfinite(fit.theta_std))


def test_model_file_round_trip_and_corruption(tmp_path, rig, plant):
    term = plant.term
    path = save_model(tmp_path / 'model.yaml', term, fitted_from='test')
    again = load_model(path, rig.fans)
    U = np.full(7, 0.4)
    np.testing.assert_allclose(again(U, rig.key_points), term(U, rig.key_points))
    bad = tmp_path / 'bad.yaml'
    bad.write_text('wind_shaper_model: 1\nmodel: {kind: fan_jets, sigma: [[[\n')
    with pytest.raises(ModelFileError, match='not readable YAML'):
        load_model(bad, rig.fans)
    with pytest.raises(ModelFileError, match='does not exist'):
        load_model(tmp_path / 'missing.yaml', rig.fans)
    (tmp_path / 'other.yaml').write_text('just: a dict\n')
    with pytest.raises(ModelFileError, match='not a wind_shaper model file'):
        load_model(tmp_path / 'other.yaml', rig.fans)


def test_loop_on_a_plant_equal_to_the_model_reaches_a_reachable_target(plant, rig):
    # A target the fans can produce exactly, so the error must fall close to the noise floor.
    U_star = np.array([0.45, 0.55, 0.4, 0.6, 0.5, 0.35, 0.2])
    target = plant.term(U_star, rig.key_points)
    loop = ShapingLoop(plant, plant.term, target, PaperUpdate(bounds=CommandBounds(0, 0.65)),
                       FieldEstimator(), u0=0.5, truth=lambda U: plant.term(U, rig.key_points))
    history = loop.run(8)
    assert len(history) == 9 and history[-1].next_pwm is None
    errors = [h.true_error for h in history]
    assert errors[-1] < 0.05 * errors[0]
    # Edge fans are well determined; the central fan's ring is spread thin over the key points,
    # so sweep noise moves it more.
    np.testing.assert_allclose(history[-1].pwm[:6], U_star[:6], atol=0.03)
    assert abs(history[-1].pwm[6] - U_star[6]) < 0.06
    assert history[0].error == pytest.approx(mean_squared_error(history[0].estimate.mean, target))
