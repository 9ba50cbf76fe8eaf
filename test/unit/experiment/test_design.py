"""Experiment designs: built from lhs:N, single-off or a file, and refused whole, with the sweep,
fan and value named, when a fan would see a command outside its range."""
import numpy as np
import pytest

from wind_shaper.core.geometry import TunnelGeometry
from wind_shaper.experiment.design import DesignError, make_design, write_design


@pytest.fixture(scope='module')
def fans():
    return TunnelGeometry.paper_rig().fans


def test_lhs_spreads_every_fan_with_fans_off_first_and_last(fans):
    d = make_design('lhs:12', fans, 0.0, 0.65, seed=3)
    assert d.commands.shape == (12, 7) and len(d.labels) == 12
    assert np.all(d.commands[0] == 0) and np.all(d.commands[-1] == 0)
    inner = d.commands[1:-1]
    assert inner.min() >= 0 and inner.max() <= 0.65
    for j in range(7):  # a Latin hypercube: one command per tenth of the range
        assert len(np.unique(np.floor(inner[:, j] / 0.065))) == 10
    assert d.spread(fans.enabled) > 0.2
    assert np.allclose(make_design('lhs:12', fans, 0.0, 0.65, seed=3).commands, d.commands)


def test_the_level_sweeps_run_every_enabled_fan_at_the_middle_and_low_before_the_last_fans_off(fans):
    plain = make_design('lhs:6', fans, 0.0, 0.65, seed=3)
    d = make_design('lhs:6+level', fans, 0.0, 0.65, seed=3)
    assert d.commands.shape == (8, 7) and list(d.labels[-3:-1]) == ['level (middle)', 'level (low)']
    assert np.allclose(d.commands[-3], 0.325) and np.allclose(d.commands[-2], 0.195)
    assert np.all(d.commands[-1] == 0)
    assert np.allclose(np.delete(d.commands, [-3, -2], axis=0), plain.commands)   # the rest as lhs:6
    disabled = TunnelGeometry.paper_rig().with_disabled(['CM']).fans
    rows = make_design('lhs:4+level', disabled, 0.1, 0.5).commands[-3:-1]
    assert np.all(rows[:, list(disabled.names).index('CM')] == 0)
    assert np.allclose(np.delete(rows[0], 6), 0.3) and np.allclose(np.delete(rows[1], 6), 0.22)
    with pytest.raises(DesignError, match=r'lhs:N\+level'):
        make_design('lhs:+level', fans, 0.0, 0.65)


def test_single_off_turns_each_fan_off_once(fans):
    d = make_design('single-off', fans, 0.0, 0.6)
    assert len(d) == 8 and np.allclose(d.commands[0], 0.3)
    assert all(np.sum(d.commands[i + 1] == 0) == 1 and d.commands[i + 1][i] == 0 for i in range(7))
    assert d.labels[1] == f'{fans.names[0]} off'


def test_a_file_design_round_trips_in_any_column_order(fans, tmp_path):
    d = make_design('lhs:5', fans, 0.0, 0.65)
    path = write_design(tmp_path / 'd.csv', d)
    again = make_design(str(path), fans, 0.0, 0.65)
    assert again.labels == d.labels and np.array_equal(again.commands, d.commands)
    names = list(reversed(fans.names))
    (tmp_path / 'r.csv').write_text(','.join(names) + '\n' + ','.join(str(0.1 * (i % 5)) for i in range(7)) + '\n')
    r = make_design(str(tmp_path / 'r.csv'), fans, 0.0, 0.65)
    assert r.commands[0][list(fans.names).index(names[1])] == pytest.approx(0.1)
    (tmp_path / 'y.yaml').write_text('design:\n' + ''.join(
        f'  - {{label: s{k}, pwm: {{{", ".join(f"{n}: 0.{k}" for n in fans.names)}}}}}\n' for k in (2, 4)))
    y = make_design(str(tmp_path / 'y.yaml'), fans, 0.0, 0.65)
    assert y.labels == ('s2', 's4') and np.allclose(y.commands[1], 0.4)


@pytest.mark.parametrize('row, needle', [
    ('0.5,0.5,0.5,0.5,0.5,0.5,0.9', r'outside the configured range \[0, 0.65\]'),
    ('0.5,0.5,0.5,0.5,0.5,0.5,nan', 'not a number'),
    ('0.5,0.5,0.5,0.5,0.5,0.5,-0.2', 'outside the configured range'),
])
def test_a_command_outside_the_range_refuses_the_whole_design(fans, tmp_path, row, needle):
    path = tmp_path / 'bad.csv'
    path.write_text('label,' + ','.join(fans.names) + '\nfirst,' + ','.join(['0.2'] * 7) + f'\nsecond,{row}\n')
    with pytest.raises(DesignError, match=needle) as err:
        make_design(str(path), fans, 0.0, 0.65)
    assert "sweep 'second'" in str(err.value) and fans.names[6] in str(err.value)


def test_wrong_fans_and_bad_specs_say_what_to_write(fans, tmp_path):
    path = tmp_path / 'fans.csv'
    path.write_text('label,' + ','.join(list(fans.names[:6]) + ['XX9']) + '\na,' + ','.join(['0.2'] * 7) + '\n')
    with pytest.raises(DesignError, match=r"missing: \['CM'\].*unknown: \['XX9'\]"):
        make_design(str(path), fans, 0.0, 0.65)
    with pytest.raises(DesignError, match='lhs:N with N >= 3'):
        make_design('lhs:2', fans, 0.0, 0.65)
    with pytest.raises(DesignError, match='unknown design'):
        make_design('grid', fans, 0.0, 0.65)
    disabled = TunnelGeometry.paper_rig().with_disabled(['CM']).fans
    d = make_design('lhs:6', disabled, 0.0, 0.65)
    assert np.all(d.commands[:, list(disabled.names).index('CM')] == 0)
    bad = tmp_path / 'cm.csv'
    bad.write_text(','.join(disabled.names) + '\n' + ','.join(['0.3'] * 7) + '\n')
    with pytest.raises(DesignError, match='disabled'):
        make_design(str(bad), disabled, 0.0, 0.65)
