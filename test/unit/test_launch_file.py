"""launch/wind_shaper.launch.py cannot run here (no `launch` on PyPI): read it as source and check
it names the same graph as `wind-shaper up`, with an entry point and a params file per node."""
import ast
from pathlib import Path

import yaml

from wind_shaper.ros import names

ROOT = Path(__file__).resolve().parents[2]
LAUNCH = ROOT / 'launch' / 'wind_shaper.launch.py'


def constants(tree):
    """Module-level NAME = <literal> assignments."""
    out = {}
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 \
                and isinstance(stmt.targets[0], ast.Name):
            try:
                out[stmt.targets[0].id] = ast.literal_eval(stmt.value)
            except ValueError:
                pass
    return out


def console_scripts():
    tree = ast.parse((ROOT / 'setup.py').read_text())
    for call in ast.walk(tree):
        if isinstance(call, ast.keyword) and call.arg == 'entry_points':
            return dict(line.replace(' ', '').split('=', 1)
                        for line in ast.literal_eval(call.value)['console_scripts'])
    raise AssertionError('setup.py has no entry_points')


def test_the_launch_file_starts_the_whole_graph():
    tree = ast.parse(LAUNCH.read_text())
    c = constants(tree)
    launched = [c['SIM_NODE'], *c['RIG_DRIVERS'], *c['OTHER_NODES']]
    assert sorted(launched) == sorted([names.SIM_TUNNEL, *names.GRAPH_NODES])
    assert c['LIVE_NODE'] == names.LIVE_VIEW
    assert len(set(launched)) == len(launched)
    assert c['SIM_NODE'] == names.SIM_TUNNEL
    functions = {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
    assert 'generate_launch_description' in functions
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)}
    assert {'sim', 'config_dir', 'rig_delay', 'wind_shaper', 'false'} <= strings
    assert {'live', 'foxglove_port'} <= strings
    imported = {(n.module or '').split('.')[0] for n in ast.walk(tree)
                if isinstance(n, ast.ImportFrom)}
    assert imported <= {'launch', 'launch_ros', 'ament_index_python'}


def test_every_launched_node_has_an_entry_point_and_a_params_file():
    c = constants(ast.parse(LAUNCH.read_text()))
    scripts = console_scripts()
    for node in [c['SIM_NODE'], *c['RIG_DRIVERS'], *c['OTHER_NODES'], c['LIVE_NODE']]:
        assert scripts.get(node) == f'wind_shaper.nodes.{node}:main', f'{node}: no entry point'
        params = ROOT / 'config' / f'{node}.yaml'
        assert params.is_file(), f'config/{node}.yaml is missing'
        doc = yaml.safe_load(params.read_text())
        assert list(doc) == [node] and 'ros__parameters' in doc[node]
        declares = 'config_dir' in doc[node]['ros__parameters']
        assert declares == (node in c['USES_CONFIG_DIR']), \
            f'{node}: USES_CONFIG_DIR disagrees with config/{node}.yaml'


def test_setup_installs_the_launch_file_and_the_configs():
    text = (ROOT / 'setup.py').read_text()
    assert "glob('launch/*.launch.py')" in text and "glob('config/*')" in text
    assert "glob('config/rviz/*.rviz')" in text
    assert LAUNCH.name.endswith('.launch.py')


def test_up_and_the_launch_file_give_every_node_the_same_parameters(tmp_path):
    """What `wind-shaper up` passes each node (plan_graph without overrides) is what the launch
    file passes: the node's own <node>.yaml from config_dir, and config_dir itself to exactly
    the nodes the launch file gives it to; with sim, sim_tunnel first and the rig drivers after."""
    from wind_shaper.supervisor import plan_graph
    c = constants(ast.parse(LAUNCH.read_text()))
    launched = [c['SIM_NODE'], *c['RIG_DRIVERS'], *c['OTHER_NODES'], c['LIVE_NODE']]
    config_dir = ROOT / 'config'
    specs = plan_graph([names.SIM_TUNNEL, *names.GRAPH_NODES, names.LIVE_VIEW], config_dir)
    assert sorted(s.name for s in specs) == sorted(launched)
    for spec in specs:
        argv = list(spec.argv)
        assert argv[argv.index('--params-file') + 1] == str(config_dir.resolve() / f'{spec.name}.yaml')
        given = [argv[i + 1].split(':=')[0] for i, a in enumerate(argv) if a == '-p']
        expected = ['config_dir'] if spec.name in c['USES_CONFIG_DIR'] else []
        assert given == expected, f'{spec.name}: up passes {given}, the launch file {expected}'
    order = [s.name for s in specs]
    assert order.index(names.SIM_TUNNEL) < min(order.index(n) for n in c['RIG_DRIVERS'])


def test_up_and_the_launch_file_put_every_node_in_the_same_namespace():
    """`wind-shaper --namespace tunnel_b up` remaps every node's namespace, as the launch file's
    namespace:=tunnel_b does for every Node it starts; without one, neither remaps."""
    from wind_shaper.supervisor import plan_graph
    text = LAUNCH.read_text()
    assert "namespace=LaunchConfiguration('namespace')" in text
    assert "DeclareLaunchArgument('namespace', default_value=''" in text
    nodes = [names.SIM_TUNNEL, *names.GRAPH_NODES]
    for spec in plan_graph(nodes, ROOT / 'config', namespace='/tunnel_b'):
        argv = list(spec.argv)
        assert argv[argv.index('-r') + 1] == '__ns:=/tunnel_b', spec.name
    for spec in plan_graph(nodes, ROOT / 'config'):
        assert '-r' not in spec.argv


def test_the_rviz_config_and_the_foxglove_layout_show_the_live_topics():
    """Both files parse and name the topics live_view publishes (RViz2 and Foxglove themselves
    cannot run here: the files are checked as data)."""
    import json
    from wind_shaper.nodes.live_view import LIVE_FANS, LIVE_FIELD, LIVE_PATH
    rviz = yaml.safe_load((ROOT / 'config' / 'rviz' / 'wind_shaper.rviz').read_text())
    manager = rviz['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == names.TUNNEL_FRAME
    topics = {d['Topic']['Value'] for d in manager['Displays'] if 'Topic' in d}
    assert topics == {'/' + t for t in (LIVE_FIELD, LIVE_FANS, LIVE_PATH, names.PLATE_POSE)}
    cloud = next(d for d in manager['Displays'] if d['Class'].endswith('PointCloud2'))
    assert cloud['Channel Name'] == 'force'
    layout = json.loads((ROOT / 'config' / 'foxglove_layout.json').read_text())
    three_d = layout['configById']['3D!wind_shaper']
    assert set(three_d['topics']) == {'/' + t for t in (LIVE_FIELD, LIVE_FANS, LIVE_PATH)}
    assert layout['layout']['first'] == '3D!wind_shaper'
