"""Bring up the whole herd graph on a full ROS 2 Jazzy install.

    ros2 launch herd_ros herd.launch.py [herd:=herd.yaml] [bag:=/path/to/bag] [rate:=30.0]

replay (bag → /herd/<agent>/fix, /clock) → gps_ingest (/herd/<agent>/odom, /herd/poses)
→ estimator (/herd/model/params, prediction, markers) → controller (/fleet/<robot>/cmd_vel,
model live from /herd/model/params) → fleet_sim (/fleet/<robot>/odom, /fleet/poses).

Nothing herd-specific lives here: the herd file (``herd:=``; default the shipped
config/herd_baboons.yaml, the demo's herd) names the agents, datum, clock step, field,
fence and robots, and :func:`herd_ros.herd_file.node_parameters` turns it into every node's
parameters — the very function ``herd-ros demo`` uses, so launch and demo cannot drift.
Write a herd file for another recording with ``herd-ros herd-file BAG -o herd.yaml``; the
demo writes the one it ran to its output folder. Each node also reads its config/*.yaml
(parameters the herd does not fix). The replay waits until every node that takes its topics
has subscribed; estimator files go to $ROS_HOME/herd_ros (~/.ros/herd_ros).
"""
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

GRAPH = ('gps_ingest', 'estimator', 'controller', 'fleet_sim', 'replay')


def _graph(context):
    from herd_ros.herd_file import node_parameters, read_herd_file
    share = Path(get_package_share_directory('herd_ros'))
    herd_file = LaunchConfiguration('herd').perform(context) or str(
        share / 'config' / 'herd_baboons.yaml')
    setup, herd_bag = read_herd_file(herd_file)
    bag = LaunchConfiguration('bag').perform(context) or herd_bag
    if not bag:
        raise RuntimeError(f'{herd_file} names no bag: give bag:=/path/to/bag')
    rate = LaunchConfiguration('rate').perform(context)
    sim_time = LaunchConfiguration('use_sim_time').perform(context).lower() in ('true', '1')
    params = node_parameters(setup, bag, rate=float(rate) if rate else None)
    nodes = []
    for name in GRAPH:
        own = dict(params[name]['ros__parameters'])
        if name != 'replay':
            own['use_sim_time'] = sim_time
        nodes.append(Node(package='herd_ros', executable=name, name=name, output='screen',
                          parameters=[str(share / 'config' / f'{name}.yaml'), own]))
    return nodes


def generate_launch_description():
    """The launch description ``ros2 launch`` runs (module docstring)."""
    return LaunchDescription([
        DeclareLaunchArgument('herd', default_value='',
                              description='herd file (herd-ros herd-file BAG writes one); '
                                          'empty = the shipped config/herd_baboons.yaml'),
        DeclareLaunchArgument('bag', default_value='',
                              description='rosbag2 of NavSatFix on /herd/<agent>/fix; empty = '
                                          'the herd file\'s bag'),
        DeclareLaunchArgument('rate', default_value='',
                              description='replay speed-up; empty = the herd file\'s rate'),
        DeclareLaunchArgument('use_sim_time', default_value='true',
                              description='follow the bag clock published by replay'),
        OpaqueFunction(function=_graph),
    ])
