"""The graph's names: relative, resolved under a namespace; namespaces checked as ROS does; bags
of a namespaced graph read under the root names."""
import pytest

from wind_shaper.bag import topics as bt
from wind_shaper.ros import names


def test_graph_names_are_relative_and_resolve_under_the_namespace():
    assert names.resolve(names.FORCE, '/') == '/wind_shaper/force'
    assert names.resolve(names.FORCE, 'tunnel_b') == '/tunnel_b/wind_shaper/force'
    assert names.resolve(names.RUN_ITERATION, '/lab/t2') == '/lab/t2/wind_shaper/run_iteration'
    # the shared ones stay absolute
    assert names.resolve(names.DIAGNOSTICS, 'tunnel_b') == '/diagnostics'
    assert names.resolve(names.MOCAP_POSE, 'tunnel_b') == names.MOCAP_POSE


def test_a_namespace_gives_its_graph_its_own_folders():
    assert names.folder_part('/') == '' and names.folder_part('tunnel_b') == 'tunnel_b'
    assert names.folder_part('/lab/tunnel_b') == 'lab_tunnel_b'


def test_the_command_line_namespace_comes_from_the_environment(monkeypatch):
    monkeypatch.delenv(names.NAMESPACE_ENV, raising=False)
    assert names.namespace_from_env() == '/' and names.resolve(names.FIELD) == '/wind_shaper/field'
    monkeypatch.setenv(names.NAMESPACE_ENV, 'tunnel_b')
    assert names.resolve(names.FIELD) == '/tunnel_b/wind_shaper/field'


@pytest.mark.parametrize('bad, part', [('2tunnel', '2tunnel'), ('tunnel-b', 'tunnel-b'),
                                       ('a//b', 'empty name'), ('tunnel_b/', 'trailing'), ('~/x', '~')])
def test_a_namespace_that_is_not_a_ros_name_is_refused_with_the_bad_part(bad, part):
    with pytest.raises(ValueError, match='not a valid ROS namespace') as err:
        names.check_namespace(bad)
    assert part in str(err.value)


def test_the_command_line_refuses_a_bad_namespace_before_doing_anything(capsys):
    from wind_shaper.cli.main import main
    assert main(['--namespace', 'tunnel-b', 'status']) == 2
    err = capsys.readouterr().err
    assert '--namespace' in err and 'not a valid ROS namespace' in err


def test_bags_of_a_namespaced_graph_are_read_under_the_root_names():
    recorded = ['/tunnel_b/wind_shaper/force', '/tunnel_b/wind_shaper/plate/pose', '/diagnostics']
    assert bt.bag_namespace(recorded) == '/tunnel_b'
    assert bt.bag_namespace(['/wind_shaper/force']) == '/'
    assert bt.canonical('/tunnel_b/wind_shaper/force') == bt.FORCE == '/wind_shaper/force'
    assert bt.in_namespace(bt.FORCE, '/tunnel_b') == '/tunnel_b/wind_shaper/force'
    assert bt.in_namespace(bt.MOCAP_POSE, '/tunnel_b') == bt.MOCAP_POSE


def test_a_sweep_bag_renamed_into_a_namespace_reads_the_same_sweeps(tmp_path):
    """A bag whose graph topics carry a namespace (as `wind-shaper --namespace tunnel_b record`
    writes them) gives the same sweeps as the bag under the root names."""
    import numpy as np

    from wind_shaper.app import Setup
    from wind_shaper.bag import BagReader, BagWriter, read_sweeps, write_sweep_bag
    from wind_shaper.workbench.commands import simulated_sweeps
    setup = Setup.load()
    data = simulated_sweeps(setup.make_sim(seed=3), 2, seed=3, n_samples=150)
    root = write_sweep_bag(tmp_path / 'root', data.sweeps, fan_names=setup.geometry.fans.names)
    with BagReader(root) as bag, BagWriter(tmp_path / 'ns') as out:
        infos = bag.topics
        for topic, info in infos.items():
            out.add_topic(bt.in_namespace(topic, '/tunnel_b'), info.msgtype)
        for topic, t_ns, raw in bag.messages():
            out.write_raw(bt.in_namespace(topic, '/tunnel_b'), t_ns, raw)
    with BagReader(tmp_path / 'ns') as bag:
        assert bt.FORCE not in bag.topics and '/tunnel_b/wind_shaper/force' in bag.topics
    a, b = read_sweeps(root), read_sweeps(tmp_path / 'ns')
    assert len(a) == len(b) >= 1
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.forces, y.forces)
        np.testing.assert_array_equal(x.positions, y.positions)
