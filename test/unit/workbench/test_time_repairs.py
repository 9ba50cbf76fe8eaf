"""Repairs of recorded sweeps for faults in time (workbench.time_repairs) and the command line
that takes them: after the repair the time checks are quiet, and the known effect beside the
fault is found as without it."""
import argparse
import json

import numpy as np
import pytest

from wind_shaper.cli.model import _data, register
from wind_shaper.core.errors import ConfigError
from wind_shaper.workbench.commands import diagnose_command
from wind_shaper.workbench.time_checks.base import batch_mean_se
from wind_shaper.workbench.time_repairs import fans_off, skip_first, zero_drift_repaired


def _off_levels(data):
    return [batch_mean_se(data.sweeps[i].forces[500:])[0] for i in fans_off(data)]


def test_the_zero_is_interpolated_between_the_fans_off_sweeps_and_its_change_subtracted(sim_data):
    data, _ = sim_data('sensor_zero_drift')
    first, last = _off_levels(data)
    assert last - first == pytest.approx(0.44, abs=0.03)
    fixed = zero_drift_repaired(data)
    a, b = _off_levels(fixed)
    assert abs(b - a) < 0.01 and a == pytest.approx(first, abs=0.01)  # the first zero stays
    # a sweep in the middle loses about half the drift
    mid = len(data) // 2
    drop = float(np.mean(data.sweeps[mid].forces - fixed.sweeps[mid].forces))
    assert drop == pytest.approx(0.22, abs=0.04)
    assert 'sensor zero interpolated' in fixed.source
    assert zero_drift_repaired(data, 'none') is data


def test_the_zero_repair_needs_two_fans_off_sweeps_and_a_known_method(sim_data):
    data, _ = sim_data('sensor_zero_drift')
    with pytest.raises(ConfigError, match='at least two sweeps with every fan off'):
        zero_drift_repaired(data[1:])
    with pytest.raises(ConfigError, match='none, interpolate'):
        zero_drift_repaired(data, 'spline')


def test_skip_first_leaves_out_the_start_of_every_sweep(sim_data):
    data, _ = sim_data()
    cut = skip_first(data, 3.0)
    assert all(len(c) == len(s) - 150 for c, s in zip(cut.sweeps, data.sweeps))
    assert all(c.times[0] >= 3.0 for c in cut.sweeps) and 'first 3 s' in cut.source
    assert skip_first(data, 0) is data
    for bad in (-1.0, float('nan'), 19.0):
        with pytest.raises(ConfigError, match='--skip-first'):
            skip_first(data, bad)


def test_repaired_sweeps_raise_no_time_alarm_and_the_weak_fan_beside_the_drift_is_found(
        wb_setup, reference, sim_data, diagnosed):
    from wind_shaper.workbench.diagnose import Diagnosis
    data, _ = sim_data('sensor_zero_drift', 'weak_fan')
    d = Diagnosis(max_effects=1).fit(reference, zero_drift_repaired(data), wb_setup.geometry)
    assert not any(r.fault for r in d.time_.values())
    assert [t.candidate.name for t in d.steps_] == ['fan_gain[HM2]']


def test_after_skipping_the_unsettled_start_the_time_checks_are_quiet(wb_setup, reference,
                                                                    diagnosed, sim_data):
    d, _ = diagnosed('unsettled_fans')
    skip = d.time_['since_command'].numbers['skip_s']
    data, _ = sim_data('unsettled_fans')
    from wind_shaper.workbench.diagnose import Diagnosis
    again = Diagnosis(check_sweeps=False, max_effects=1).fit(reference, skip_first(data, skip),
                                                             wb_setup.geometry)
    assert not any(r.fault for r in again.time_.values())


def _args(*extra):
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    return parser.parse_args(['model', 'diagnose', '--sim', '--hidden', 'sensor_zero_drift',
                              '--sweeps', '6', '--samples', '400', '--seed', '3', *extra])


def test_every_model_command_takes_the_time_repairs(wb_setup):
    mended = _data(wb_setup, _args('--zero-drift', 'interpolate', '--skip-first', '1.5'))
    assert 'sensor zero interpolated' in mended.source and 'first 1.5 s' in mended.source
    assert all(s.times[0] >= 1.5 for s in mended.sweeps)
    with pytest.raises(SystemExit):
        _args('--zero-drift', 'guess')


def test_the_diagnosis_report_names_the_drift_and_its_repair(wb_setup, reference, sim_data, tmp_path):
    data, built = sim_data('sensor_zero_drift')
    d = diagnose_command(reference, data, wb_setup.geometry, tmp_path, truth=built)
    doc = json.loads((tmp_path / 'summary.json').read_text())
    assert doc['verdict'] == 'time fault' and doc['findings'] == []
    zero = next(t for t in doc['time'] if t['check'] == 'sensor_zero')
    assert zero['result'] == 'fault' and zero['repair'] == '--zero-drift interpolate'
    assert zero['numbers']['moved_N'] == pytest.approx(0.44, abs=0.05)
    report = (tmp_path / 'report.md').read_text()
    assert 'force sensor\'s zero moved' in report and '--zero-drift interpolate' in report
    assert d.verdict_ == 'time fault'
