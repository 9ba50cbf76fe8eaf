"""Data sets (design, split by sweep, cell means, sources), fitting with uncertainties, the
held-out model error, the reference model, residual analysis and reports."""
import json

import numpy as np
import pytest

from wind_shaper.model import CentralRing, FanGain, FanJets
from wind_shaper.core.geometry import TunnelGeometry
from wind_shaper.core.tunnel import Sweep
from wind_shaper.sim import Imperfections, NoiseModel, SimulatedTunnel
from wind_shaper.workbench import (DataSourceError, Frozen, HeldOut, SweepSet, analyse_residuals,
                                   design_commands, fit_model, from_report, from_run_folder,
                                   jackknife_std, scores)
from wind_shaper.workbench.commands import simulated_sweeps
from wind_shaper.workbench.report import Report, plot_residual_maps


@pytest.fixture(scope='module')
def rig():
    return TunnelGeometry.paper_rig()


@pytest.fixture(scope='module')
def truth_model(rig):
    jets = FanJets(rig.fans, thrust_higher=(0.0, 1.0, 11.0), thrust_lower=(0.0, 0.8, 9.0), sigma=0.16)
    return FanGain(rig.fans, jets + CentralRing(rig.fans, thrust=(0.0, 0.5, 8.0), offset=0.6, sigma=0.25),
                   fan='HM2', gain=0.8)


def _synthetic(model, rig, n_sweeps, noise, seed=0, n=400):
    """Sweeps whose forces are ``model`` plus white noise [N] at random plate positions."""
    rng = np.random.default_rng(seed)
    U = design_commands(7, n_sweeps, seed=seed)
    sweeps = []
    for u in U:
        r = 0.34 * np.sqrt(rng.uniform(size=n))
        a = rng.uniform(0, 2 * np.pi, n)
        Z = np.column_stack([r * np.cos(a), r * np.sin(a)])
        sweeps.append(Sweep(Z, model(u, Z) + noise * rng.standard_normal(n), np.arange(n) * 0.02, u))
    return SweepSet(tuple(sweeps), rig.fans.names, 'synthetic')


def test_design_spreads_every_fan_over_the_range_uncorrelated():
    U = design_commands(7, 20, high=0.9, seed=3)
    assert U.shape == (20, 7) and U.min() >= 0 and U.max() <= 0.9
    for col in U.T:  # one command per twentieth of the range (Latin hypercube)
        assert sorted(np.floor(col / 0.045).astype(int).tolist()) == list(range(20))
    corr = np.corrcoef(U.T)
    assert np.max(np.abs(corr[np.triu_indices(7, 1)])) < 0.6
    assert (design_commands(7, 5, enabled=[True] * 6 + [False])[:, 6] == 0).all()


def test_split_by_sweep_folds_and_cell_means(rig, truth_model):
    data = _synthetic(truth_model, rig, 9, 0.0)
    train, test = data.split()
    assert len(train) + len(test) == 9 and set(train.labels).isdisjoint(test.labels)
    assert test.labels == ('#2', '#5', '#8')
    folds = data.folds(3)
    assert sorted(sum((list(t.labels) for _, t in folds), [])) == sorted(data.labels)
    fd = data.fit_data(0.04)
    assert len(fd) < data.n_samples and fd.count.sum() == data.n_samples
    np.testing.assert_allclose(truth_model(fd.U, fd.Z), fd.y, atol=0.15)  # cell means near the field
    with pytest.raises(DataSourceError, match='2 sweeps'):
        data[:1].split()
    with pytest.raises(DataSourceError, match='fans'):
        data.check_fans(['A', 'B'])


def test_fit_recovers_parameters_with_honest_uncertainty(rig, truth_model):
    data = _synthetic(truth_model, rig, 8, 0.05).fit_data(None)
    start = truth_model.with_theta(np.clip(truth_model.theta * 1.15, *truth_model.bounds.T))
    fit = fit_model(start, data, max_nfev=200)
    z = (fit.theta - truth_model.theta) / fit.theta_std
    assert np.all(np.abs(z) < 4.5), dict(zip(fit.names, np.round(z, 1)))
    assert fit.rmse == pytest.approx(0.05, rel=0.1) and fit.converged
    # fitting only some parameters leaves the others alone
    off = truth_model.with_theta(np.r_[truth_model.theta[:-1], 1.0])
    part = fit_model(off, data, free=[len(off.theta) - 1])
    np.testing.assert_allclose(part.model.theta[:-1], off.theta[:-1])
    assert part.model.theta[-1] == pytest.approx(0.8, abs=0.01)
    jk = jackknife_std(part.model, data, [len(start.theta) - 1])
    assert 0 < jk[0] < 0.05


def test_frozen_model_is_cached_and_has_no_parameters(rig, truth_model):
    frozen = Frozen(truth_model)
    U = np.full((50, 7), 0.4)
    Z = np.random.default_rng(0).uniform(-0.3, 0.3, (50, 2))
    a = frozen(U, Z)
    assert frozen(U, Z) is not None and len(frozen.theta) == 0 and frozen.with_theta([]) is frozen
    np.testing.assert_array_equal(a, truth_model(U, Z))
    wrapped = FanGain(rig.fans, frozen, fan='LM1', gain=1.2)
    assert len(wrapped.theta) == 1
    np.testing.assert_allclose(wrapped(U, Z), FanGain(rig.fans, truth_model, fan='LM1', gain=1.2)(U, Z))


def test_heldout_model_error_removes_the_turbulence(rig):
    """On the simulated tunnel the noise-corrected error matches the error against the true field."""
    from wind_shaper.model import paper_prior
    sim = SimulatedTunnel(rig, seed=2, imperfections=Imperfections.none(7), noise=NoiseModel())
    train, test = simulated_sweeps(sim, 7, seed=2).split(test=[2, 4, 6])
    model = fit_model(paper_prior(rig.fans), train.fit_data(0.04), max_nfev=100).model
    ho = HeldOut(test)
    ev = ho.evaluate(model)
    true_err = np.sqrt(np.mean(np.concatenate([
        model(s.pwm, s.positions) - sim.true_field(s.pwm, s.positions) for s in test.sweeps]) ** 2))
    assert len(ho.pairs) > 200 and ev['noise_sd'] > 0.1
    assert ev['raw'].rmse > ev['model_rmse'] + 0.02  # the turbulence is taken out
    assert ev['model_rmse'] == pytest.approx(true_err, abs=max(ev['resolution'], 0.03))
    s = scores(np.zeros(3), np.array([1.0, 2.0, 3.0]))
    assert s.rmse == pytest.approx(np.sqrt(14 / 3)) and s.max_error == 3.0 and s.bias == 2.0


@pytest.mark.slow
def test_commissioning_recovers_each_fans_build(wb_setup):
    """The reference commissioned on the calibration batch predicts the (effect-free) tunnel's
    true field at new commands within a few hundredths of a newton, puts each jet where the
    build put it, and keeps only the thrust polynomials free."""
    from wind_shaper.workbench.reference import commission_on
    sim = wb_setup.make_sim(seed=100)
    ref = commission_on(sim)
    kp = wb_setup.geometry.key_points
    U = design_commands(7, 6, high=0.7, seed=9)
    err = np.concatenate([ref.model(u, kp) - sim.true_field(u, kp) for u in U])
    assert np.sqrt(np.mean(err ** 2)) < 0.1
    truth = sim.imperfections.as_dict(wb_setup.geometry.fans.names)
    build = ref.build()
    for n in truth:
        np.testing.assert_allclose(build[n]['offset_m'], truth[n]['offset'], atol=0.003)
    assert ref.fit.rmse < 0.05
    assert len(ref.model.theta_names) == 9 and all('thrust' in n for n in ref.model.theta_names)


def test_residual_analysis_points_at_the_fan_and_the_place(rig, truth_model):
    base = truth_model.inner  # the model without HM2's weakness
    data = _synthetic(truth_model, rig, 10, 0.05, seed=4).fit_data(0.04)
    a = analyse_residuals(base, data, rig)
    assert a.top_fans(1)[0][0] == 'HM2'
    where, value = a.peak()
    assert np.hypot(*(where - rig.fans.positions[rig.fans.index('HM2')])) < 0.06 and value < 0
    assert max(a.fan_share, key=a.fan_share.get) == 'HM2'
    text = ' '.join(a.describe())
    assert "follows fan HM2's command" in text and 'high' in text
    doc = a.to_json()
    json.dumps(doc)
    assert doc['fan_r2']['HM2'] > 0.3


def test_report_writes_html_markdown_pngs_and_json(rig, truth_model, tmp_path):
    data = _synthetic(truth_model, rig, 4, 0.05).fit_data(0.04)
    a = analyse_residuals(truth_model.inner, data, rig)
    rep = Report('a test report')
    rep.text('hello', heading='Intro')
    rep.table(['a', 'b'], [[1, 2]])
    rep.figure('maps', plot_residual_maps({'before': a}, rig), 'the maps')
    rep.summary = {'x': np.float64(1.5), 'arr': np.arange(3)}
    out = rep.write(tmp_path / 'r')
    html = (out / 'report.html').read_text()
    assert 'data:image/png;base64,' in html and '<h2>Intro</h2>' in html
    assert '![the maps](maps.png)' in (out / 'report.md').read_text()
    assert (out / 'maps.png').read_bytes()[:4] == b'\x89PNG'
    assert json.loads((out / 'summary.json').read_text()) == {'x': 1.5, 'arr': [0, 1, 2]}


def test_sweeps_from_a_run_folder_and_a_shape_report(rig, tmp_path, wb_setup):
    from wind_shaper.app import shape_on_sim
    from wind_shaper.report.run_report import write_report
    records, _ = shape_on_sim(wb_setup, 'uniform', iterations=2, seed=1)
    write_report(tmp_path / 'shape', records, wb_setup.geometry, {})
    got = from_report(tmp_path / 'shape')
    assert len(got) == 3 and got.fan_names == wb_setup.geometry.fans.names
    np.testing.assert_allclose(got.sweeps[1].forces, records[1].sweep.forces)
    pytest.importorskip('wind_shaper.storage.runstore', reason='the run folder needs storage.runstore')
    from wind_shaper.storage.runstore import IterationData, RunInfo, RunStore
    info = RunInfo('uniform', wb_setup.geometry.fans.names, wb_setup.geometry.key_points, {})
    store = RunStore.open(tmp_path / 'runs', 'r1', info, initial_pwm=records[0].pwm)
    for r in records[:2]:
        store.write_iteration(IterationData(k=r.k, pwm_before=r.pwm, pwm_after=r.next_pwm, step_size=0.5,
                                            rmse=1.0, rmse_predicted_after=0.9, estimate=r.estimate,
                                            target='uniform', target_values=r.target, sweep=r.sweep,
                                            model='m'))
    run = from_run_folder(tmp_path / 'runs' / 'r1')
    assert run.labels == ('run k=0', 'run k=1')
    np.testing.assert_allclose(run.sweeps[1].positions, records[1].sweep.positions)
    with pytest.raises(DataSourceError, match='not a run folder'):
        from_run_folder(tmp_path)
