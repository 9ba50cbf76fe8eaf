"""The wind_shaper node graph for a full ROS 2 install (`wind-shaper up` does the same here).

    ros2 launch wind_shaper wind_shaper.launch.py                 # on the rig
    ros2 launch wind_shaper wind_shaper.launch.py sim:=true       # on the simulated rig
    ros2 launch wind_shaper wind_shaper.launch.py config_dir:=/path/to/lab/config
    ros2 launch wind_shaper wind_shaper.launch.py namespace:=tunnel_b   # a second tunnel
    ros2 launch wind_shaper wind_shaper.launch.py sim:=true live:=true foxglove_port:=8765

Each node reads config_dir/<node>.yaml; the nodes that also read the core's tunnel.yaml,
shaping.yaml, model.yaml, sim.yaml get config_dir as their config_dir parameter. With
sim:=true, sim_tunnel starts first and the rig drivers (fan_output, force_sensor) follow after
rig_delay seconds, so they find its UDP sockets open. With live:=true, live_view publishes the
field, the fans and the sweep path for RViz2 (and serves them to Foxglove with foxglove_port).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, GroupAction, TimerAction
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

#: Every node of the graph, sim_tunnel only with sim:=true.
SIM_NODE = 'sim_tunnel'
RIG_DRIVERS = ('fan_output', 'force_sensor')
OTHER_NODES = ('mocap_relay', 'field_estimator', 'coordinator')
#: The optional live view (live:=true), as `wind-shaper up --live`.
LIVE_NODE = 'live_view'
#: Nodes that read the core's YAML files through their config_dir parameter.
USES_CONFIG_DIR = ('sim_tunnel', 'field_estimator', 'coordinator', 'live_view')


def node(name, **extra):
    config_dir = LaunchConfiguration('config_dir')
    parameters = [PathJoinSubstitution([config_dir, name + '.yaml'])]
    if name in USES_CONFIG_DIR:
        parameters.append({'config_dir': config_dir})
    if extra:
        parameters.append(extra)
    return Node(package='wind_shaper', executable=name, name=name, output='screen',
                emulate_tty=True, parameters=parameters,
                namespace=LaunchConfiguration('namespace'))


def generate_launch_description():
    default_config = os.path.join(get_package_share_directory('wind_shaper'), 'config')
    sim = LaunchConfiguration('sim')
    return LaunchDescription([
        DeclareLaunchArgument('sim', default_value='false',
                              description='true: start sim_tunnel, the simulated rig on 127.0.0.1'),
        DeclareLaunchArgument('config_dir', default_value=default_config,
                              description='folder with <node>.yaml per node and the core YAML '
                                          'files (tunnel, shaping, model, sim)'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='ROS namespace of every node (the graph\'s names are '
                                          'relative: /NS/wind_shaper/...); as wind-shaper '
                                          '--namespace NS up'),
        DeclareLaunchArgument('rig_delay', default_value='3.0',
                              description='with sim:=true, start the rig drivers this many seconds '
                                          'after sim_tunnel [s]'),
        *[node(name) for name in OTHER_NODES],
        GroupAction([node(SIM_NODE),
                     TimerAction(period=LaunchConfiguration('rig_delay'),
                                 actions=[node(name) for name in RIG_DRIVERS])],
                    condition=IfCondition(sim)),
        GroupAction([node(name) for name in RIG_DRIVERS], condition=UnlessCondition(sim)),
        DeclareLaunchArgument('live', default_value='false',
                              description='true: start live_view (wind_shaper/live/* for RViz2)'),
        DeclareLaunchArgument('foxglove_port', default_value='0',
                              description='with live:=true, serve the live view to Foxglove on '
                                          'this WebSocket port (0 = off)'),
        GroupAction([node(LIVE_NODE, foxglove_port=ParameterValue(
            LaunchConfiguration('foxglove_port'), value_type=int))],
                    condition=IfCondition(LaunchConfiguration('live'))),
    ])
