"""Time in the diagnosis (workbench.time_checks): each check fires on its fault in simulated
sweeps and keeps quiet on clean ones; while a fault in time stands no effect is named, and the
verdict says what the fault is, what to do at the rig and which repair to give."""
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from wind_shaper.core.tunnel import Sweep
from wind_shaper.sim import SensorZeroDrift
from wind_shaper.workbench.data import SweepSet
from wind_shaper.workbench import verdict
from wind_shaper.workbench.diagnose import Diagnosis
from wind_shaper.workbench.time_checks import (TIME_CHECKS, Recording, TimeCheck, check_time,
                                               register_time_check)


def _recording(data, reference, wb_setup, noise_sd=0.18):
    return Recording.of(data, reference, noise_sd=noise_sd, material=0.5, z=4.0,
                        enabled=wb_setup.geometry.fans.enabled)


def _run(rec):
    out = {}
    for name, check in TIME_CHECKS.items():
        out[name] = check.measure(rec, dict(out))
    return out


def test_a_drifting_zero_is_named_with_the_fans_off_sweeps_and_its_repair(diagnosed):
    d, _ = diagnosed('sensor_zero_drift')
    zero = d.time_['sensor_zero']
    assert zero.fault and zero.numbers['first_to_last_N'] == pytest.approx(0.44, abs=0.05)
    assert d.verdict_ == 'time fault' and d.steps_ == []
    text = d.summary()
    assert 'zero moved +0.4' in text and 'first and the last fans-off sweep' in text
    assert '--zero-drift interpolate' in text and 'Bias the sensor' in text
    assert not d.time_['since_command'].fault and not d.time_['within_sweep'].fault


def test_sweeps_started_before_the_fans_settled_are_named_with_the_skip(diagnosed):
    d, _ = diagnosed('unsettled_fans')
    settle = d.time_['since_command']
    assert settle.fault and 0.75 <= settle.numbers['tau_s'] <= 3.0
    assert 0.5 < settle.numbers['share_at_start'] < 1.5
    skip = settle.numbers['skip_s']
    assert 2.0 <= skip <= 10.0
    text = d.summary()
    assert f'first {skip:g} s of each sweep read the previous commands' in text
    assert 'settle_s' in text and f'--skip-first {skip:g}' in text
    assert d.verdict_ == 'time fault' and not d.time_['sensor_zero'].fault


def test_clean_sweeps_raise_no_time_alarm(diagnosed):
    d, _ = diagnosed()
    assert [r.check for r in d.time_.values() if r.fault] == []
    assert d.verdict_ != 'time fault' and d.time_warning() == ''
    doc = d.to_json()
    assert [t['result'] for t in doc['time']] == ['none'] * len(TIME_CHECKS)


def test_a_known_effect_raises_no_time_alarm(diagnosed):
    d, _ = diagnosed('weak_fan')
    assert not any(r.fault for r in d.time_.values())


def test_a_trend_over_the_recording_follows_the_order_and_the_within_sweep_slope_is_the_same(
        wb_setup, reference, sim_data):
    data, _ = sim_data(SensorZeroDrift(rate=0.01))   # 2.2 N over the recording
    out = _run(_recording(data, reference, wb_setup))
    order = out['recording_order']
    assert order.fault and order.numbers['per_sweep_N'] == pytest.approx(0.2, abs=0.03)
    assert 'follows the recording order' in order.message
    within = out['within_sweep']
    assert within.fault is False and within.numbers.get('same_as_recording_drift')


def test_a_ramp_within_every_sweep_is_named_and_not_the_order(wb_setup, reference, sim_data):
    data, _ = sim_data()
    # a sensor that warms up after a bias at each sweep's start: +0.3 N over 20 s, every sweep
    ramped = SweepSet(tuple(Sweep(s.positions, s.forces + 0.015 * s.times, s.times, s.pwm)
                            for s in data.sweeps), data.fan_names, data.source, data.labels)
    out = _run(_recording(ramped, reference, wb_setup))
    assert out['within_sweep'].fault and 'within the sweeps' in out['within_sweep'].message
    assert not out['recording_order'].fault and not out['sensor_zero'].fault


def test_a_pattern_fixed_in_space_that_the_paths_meet_late_is_no_drift(wb_setup, reference, sim_data):
    """Each sweep gets a residual fixed in space (per 3 cm cell, the mean time its own path was
    there, 0.3 N over a sweep): over time it rises in every sweep, as a wall layer does on paths
    that leave the axis, but a place visited twice reads the same. The within-sweep check takes
    its slopes from those revisits and calls no drift; the plain slope over time did."""
    data, _ = sim_data()
    patterned = []
    for s in data.sweeps:
        cells = np.floor(s.positions / 0.03).astype(int)
        _, cell, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
        cell = cell.ravel()
        when = np.bincount(cell, weights=s.times) / counts       # the mean time in each cell [s]
        patterned.append(Sweep(s.positions, s.forces + 0.3 * when[cell] / s.times[-1], s.times, s.pwm))
    out = _run(_recording(SweepSet(tuple(patterned), data.fan_names, data.source, data.labels),
                          reference, wb_setup))
    within = out['within_sweep']
    assert not within.fault, within.message
    assert within.numbers['sweeps_from_revisits'] >= 10


def test_the_time_checks_can_be_switched_off_and_a_fault_need_not_hold_the_findings(diagnosed):
    d, _ = diagnosed('sensor_zero_drift')
    off = SimpleNamespace(settings=Diagnosis(check_time=False), time={'x': 1}, held=True)
    assert check_time(off).time == {} and not off.held
    # the same recording with hold_on_time_fault off: the fault is a warning beside the verdict
    case = replace(d.case_, settings=Diagnosis(hold_on_time_fault=False), time={}, held=False)
    case = check_time(case)
    assert not case.held and case.time['sensor_zero'].fault
    assert verdict.time_warning(case).startswith('The sweeps depend on when they were recorded')


def test_a_new_time_check_is_one_registered_class(diagnosed, wb_setup, reference, sim_data):
    @register_time_check
    class Always(TimeCheck):
        name, question = 'always_for_test', 'Is this test running?'

        def measure(self, rec, earlier):
            assert set(earlier) == {'sensor_zero', 'recording_order', 'since_command', 'within_sweep'}
            return self.result(True, {'sweeps': len(rec.sweeps)}, 'the test says so', '--skip-first 1')
    try:
        data, _ = sim_data()
        d = Diagnosis(check_sweeps=False).fit(reference, data, wb_setup.geometry)
        assert d.verdict_ == 'time fault' and 'the test says so' in d.summary()
        assert '`--skip-first 1`' in d.summary()
    finally:
        TIME_CHECKS.pop('always_for_test')
    with pytest.raises(TypeError, match='name and a question'):
        register_time_check(type('Nameless', (TimeCheck,), {}))
