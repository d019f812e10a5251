"""Herding on a full ROS 2 Jazzy install: robots drive simulated sheep into a goal circle.

    ros2 launch herd_ros herding.launch.py [animals:=14] [herders:=1] [rate:=10.0] [seed:=0]
        [herder:=strombom|model]

herd_sim (Strömbom's sheep, fleeing every robot of /fleet/poses; publishes /herd/poses and
drives /clock, rate × real time) → controller (mode herding: Strömbom's shepherd, or the
model herder with ``herder:=model``; goal, herd centre and targets as RViz markers on
/herding/markers) → fleet_sim (the herders;
/fleet/<robot>/odom, /fleet/poses). The parameters come from
:func:`herd_ros.herding.live_graph.herding_parameters`, the function ``herd-ros demo
--herding`` runs the same graph with; each node also reads its config/*.yaml (the
controller config/herding.yaml).
"""
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

GRAPH = ('herd_sim', 'fleet_sim', 'controller')
CONFIG = {'herd_sim': 'herd_sim.yaml', 'fleet_sim': 'fleet_sim.yaml',
          'controller': 'herding.yaml'}


def _graph(context):
    from herd_ros.herding.live_graph import herding_parameters
    share = Path(get_package_share_directory('herd_ros'))

    def arg(name, kind):
        return kind(LaunchConfiguration(name).perform(context))
    params = herding_parameters(arg('animals', int), arg('herders', int), arg('rate', float),
                                arg('seed', int), herder=arg('herder', str),
                                model_warmup=arg('model_warmup', str))
    return [Node(package='herd_ros', executable=name, name=name, output='screen',
                 parameters=[str(share / 'config' / CONFIG[name]),
                             params[name]['ros__parameters']])
            for name in GRAPH]


def generate_launch_description():
    """The launch description ``ros2 launch`` runs (module docstring)."""
    return LaunchDescription([
        DeclareLaunchArgument('animals', default_value='14', description='number of sheep'),
        DeclareLaunchArgument('herders', default_value='1', description='number of robots'),
        DeclareLaunchArgument('rate', default_value='10.0',
                              description='simulated seconds per wall second'),
        DeclareLaunchArgument('seed', default_value='0',
                              description="seed of the sheep's start and noise"),
        DeclareLaunchArgument('herder', default_value='strombom',
                              description="the robots' policy: strombom or model"),
        DeclareLaunchArgument('model_warmup', default_value='strombom',
                              description='herder model: what the robots do while it learns, '
                                          'strombom or hold'),
        OpaqueFunction(function=_graph),
    ])
