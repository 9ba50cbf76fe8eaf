"""The commissioning's wiring check: two fans whose command channels are exchanged are named
from the designed sweeps; sweeps wired as configured are passed; the calibration carries the
verdict into its summary, the model file and its report."""
from dataclasses import replace

import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.experiment.design import make_design
from wind_shaper.workbench.calibrate import calibrate_default_prior
from wind_shaper.workbench.data import from_sim
from wind_shaper.workbench.wiring import MARGIN, check_wiring


class _Miswired:
    """The simulated tunnel with fans ``a`` and ``b`` on each other's output: each gets the
    other's command, and the sweep records the commands as sent."""

    def __init__(self, tunnel, a: int, b: int):
        self.tunnel, self.a, self.b = tunnel, a, b
        self.geometry = tunnel.geometry
        self._sent = None

    def apply(self, U):
        self._sent = np.array(U, float)
        driven = self._sent.copy()
        driven[[self.a, self.b]] = self._sent[[self.b, self.a]]
        self.tunnel.apply(driven)

    def sweep(self, n_samples):
        return replace(self.tunnel.sweep(n_samples), pwm=self._sent.copy())


def _designed_sweeps(swap=None, seed=0):
    setup = Setup.load()
    fans = setup.geometry.fans
    sim = setup.make_sim(seed=seed)
    tunnel = sim if swap is None else _Miswired(sim, fans.index(swap[0]), fans.index(swap[1]))
    design = make_design('lhs:6+level', fans, setup.shaping.u_min, setup.shaping.u_max, seed=seed)
    return setup, from_sim(tunnel, design.commands, n_samples=setup.shaping.samples_per_sweep)


@pytest.mark.parametrize('swap', [('HM1', 'LM3'), ('LM1', 'HM1'), ('CM', 'LM2')])
def test_two_fans_on_each_others_outputs_are_named(swap):
    setup, data = _designed_sweeps(swap)
    cal = calibrate_default_prior(data, setup.geometry.fans)
    assert cal.wiring.checked and set(cal.wiring.swapped) == set(swap)
    assert cal.wiring.rmse_swapped < MARGIN * cal.wiring.rmse_as_wired
    text = cal.wiring.text
    assert swap[0] in text and swap[1] in text and 'channels' in text and 'fan_output.yaml' in text
    assert cal.summary()['wiring']['swapped'] == list(cal.wiring.swapped)


@pytest.mark.parametrize('seed', [0, 1])
def test_sweeps_wired_as_configured_pass(seed):
    setup, data = _designed_sweeps(None, seed)
    cal = calibrate_default_prior(data, setup.geometry.fans)
    assert cal.wiring.checked and cal.wiring.swapped is None
    assert cal.wiring.rmse_swapped > cal.wiring.rmse_as_wired   # no exchange fits better at all
    assert 'as configured' in cal.wiring.text


def test_the_check_says_why_it_did_not_run():
    setup, data = _designed_sweeps(None)
    few = replace(data, sweeps=data.sweeps[:2], labels=data.labels[:2])
    verdict = check_wiring(few, setup.geometry.fans)
    assert not verdict.checked and 'three sweeps' in verdict.text


def test_the_calibration_report_and_model_file_carry_the_verdict(tmp_path, capsys):
    from wind_shaper.cli.main import _report_calibration
    from wind_shaper.core.safe_yaml import read_yaml_file
    setup, data = _designed_sweeps(('HM1', 'LM3'))
    cal = calibrate_default_prior(data, setup.geometry.fans)
    out = tmp_path / 'model.yaml'
    assert _report_calibration(cal, out, setup) == 0
    captured = capsys.readouterr()
    assert 'WIRING' in captured.err and 'HM1' in captured.err
    doc = read_yaml_file(out)
    assert sorted(doc['wiring_check']['swapped']) == ['HM1', 'LM3'] and 'model' in doc   # the fit is kept
