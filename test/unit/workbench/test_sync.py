"""Forces and positions out of step (sync.check_sync): the lag between motion capture and the
force sensor is measured from the sweeps, and the diagnosis says so in words."""
import re
from dataclasses import replace

import numpy as np
import pytest

from wind_shaper.core.tunnel import Sweep
from wind_shaper.sim import MocapLatency
from wind_shaper.core.errors import ConfigError
from wind_shaper.workbench.sync import check_sync, repaired


def _late_by(data, lag):
    """The sweeps with each position taken ``lag`` [s] later in the path (lag < 0: earlier)."""
    out = []
    for s in data.sweeps:
        t = s.times
        moved = np.column_stack([np.interp(t + lag, t, s.positions[:, k]) for k in range(2)])
        out.append(Sweep(moved, s.forces, s.times, s.pwm))
    return replace(data, sweeps=tuple(out))


def test_in_step_sweeps_show_no_lag_even_beside_physics_the_model_lacks(reference, sim_data):
    for effects in ((), ('honeycomb_blockage',), ('side_draft',)):
        data, _ = sim_data(*effects)
        check = check_sync(reference, data)
        assert abs(check.lag_s) < 0.005 and not check.out_of_step, effects
        assert check.text() == ''


def test_a_late_recording_is_measured_in_either_direction(reference, sim_data):
    data, _ = sim_data(MocapLatency(lag=0.04))
    check = check_sync(reference, data)
    assert check.lag_s == pytest.approx(0.04, abs=0.003) and check.out_of_step
    assert len(check.per_sweep) == 10  # the two fans-off sweeps cannot show it
    assert check.agree == 1.0 and check.drop > 0.5
    assert 'positions arrive 40 ms late' in check.text()
    # the positions early instead: the clean sweeps with each position taken 60 ms later
    clean, _ = sim_data()
    early = check_sync(reference, _late_by(clean, 0.06))
    assert early.lag_s == pytest.approx(-0.06, abs=0.004) and early.out_of_step
    assert 'positions arrive 60 ms early' in early.text()


def test_sweeps_that_cannot_show_a_lag_give_none(reference, sim_data):
    data, _ = sim_data()
    off = data[[0, len(data) - 1]]  # the fans-off sweeps
    assert check_sync(reference, off) is None
    still = replace(data, sweeps=tuple(Sweep(np.zeros_like(s.positions), s.forces, s.times, s.pwm)
                                       for s in data.sweeps))
    assert check_sync(reference, still) is None


def test_the_diagnosis_says_the_clocks_disagree(diagnosed):
    d, _ = diagnosed(MocapLatency(lag=0.04))
    assert d.sync_.out_of_step
    assert 'look out of step' in d.summary()
    doc = d.to_json()
    assert doc['clocks']['out_of_step'] and doc['clocks']['lag_s'] == pytest.approx(0.04, abs=0.003)
    assert any('out of step' in w for w in doc['warnings'])


def test_re_paired_sweeps_are_in_step_again(reference, sim_data):
    data, _ = sim_data(MocapLatency(lag=0.04))
    late = check_sync(reference, data)
    assert '--position-lag 0.040' in late.text()
    mended = repaired(data, late.lag_s)
    check = check_sync(reference, mended)
    assert abs(check.lag_s) < 0.003 and not check.out_of_step
    assert [s.forces.tolist() for s in mended.sweeps] == [s.forces.tolist() for s in data.sweeps]
    assert 're-paired +40 ms' in mended.source
    assert repaired(data, 0.0) is data
    for bad in (float('nan'), 2.0, 'soon'):
        with pytest.raises((ConfigError, ValueError), match='seconds|could not convert'):
            repaired(data, bad)


def test_every_model_command_takes_the_position_lag(wb_setup, reference):
    import argparse

    from wind_shaper.cli.model import _data, register
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(['model', 'diagnose', '--sim', '--hidden', 'mocap_latency:lag=0.06',
                              '--sweeps', '6', '--samples', '400', '--seed', '3', '--position-lag', '0.06'])
    mended = _data(wb_setup, args)
    assert 're-paired +60 ms' in mended.source
    assert not check_sync(reference, mended).out_of_step
    args.position_lag = 0.0
    assert check_sync(reference, _data(wb_setup, args)).lag_s == pytest.approx(0.06, abs=0.004)


def test_a_clock_that_steps_during_the_experiment_is_found_in_the_sweeps_it_hit(reference, sim_data):
    clean, _ = sim_data()
    for lag, way in ((0.4, 'early'), (-0.15, 'late')):
        check = check_sync(reference, repaired(clean, lag, only=(7, 8, 9)))
        # the median over the sweeps is in step: the run-wide check sees nothing
        assert abs(check.lag_s) < 0.005 and not check.out_of_step
        assert check.stepped == (7, 8, 9), (lag, check.per_sweep)
        text = check.text()
        names = ', '.join(clean.labels[i] for i in (7, 8, 9))
        assert f'Sweeps {names} of 10' in text
        said = re.search(r'positions arrive (\d+) ms (\w+)', text)
        assert abs(int(said.group(1)) - 1000 * abs(lag)) <= 3 and said.group(2) == way, text
        assert 'Record them again' in text
    # one sweep alone is named too
    one = check_sync(reference, repaired(clean, 0.25, only=(3,)))
    assert one.stepped == (3,) and 'looks out of step on its own' in one.text()


def test_a_step_shorter_than_its_threshold_or_in_most_sweeps_names_no_sweep(reference, sim_data):
    clean, _ = sim_data()
    assert check_sync(reference, repaired(clean, 0.03, only=(7, 8, 9))).stepped == ()
    # most sweeps moved alike: that is the clocks out of step as a whole, said as before
    whole = check_sync(reference, repaired(clean, -0.06, only=range(1, 10)))
    assert whole.stepped == () and whole.out_of_step and 'Sweeps' not in whole.text()
