"""Bring up the whole herd graph on a full ROS 2 Jazzy install.

    ros2 launch herd_ros herd.launch.py [bag:=/path/to/bag] [rate:=10.0] [use_sim_time:=true]

replay (bag → /herd/<cow>/fix, /clock) → gps_ingest (/herd/<cow>/odom, /herd/poses)
→ estimator (/herd/model/params, prediction, markers) → controller (/fleet/<robot>/cmd_vel,
model live from /herd/model/params) → fleet_sim (/fleet/<robot>/odom, /fleet/poses).

Parameters come from the package's config/*.yaml; the herd (`agents`), the clock step and the
field grid are set once here so every node agrees. On the pip path (no `launch` package) the
same graph runs in one process with `herd-ros demo`.
"""
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

AGENTS = ['cow_1', 'cow_2', 'cow_3']
ROBOTS = ['robot_1', 'robot_2', 'robot_3']
DT = 20.0
FIELD_GRID = [4, 3]          # coarse: one hour of collar data cannot carry a fine field
FIELD_BOUNDS = [-200.0, 200.0, -150.0, 150.0]   # the paddock, about the datum below
DATUM = [27.0153, -108.7937, 0.0]


def generate_launch_description():
    share = Path(get_package_share_directory('herd_ros'))
    config = share / 'config'
    bag = LaunchConfiguration('bag')
    rate = LaunchConfiguration('rate')
    sim_time = LaunchConfiguration('use_sim_time')
    use_sim_time = {'use_sim_time': ParameterValue(sim_time, value_type=bool)}
    herd = {'agents': AGENTS, 'dt': DT}
    field = {'field_grid': FIELD_GRID, 'field_bounds': FIELD_BOUNDS}

    def node(executable, *params):
        return Node(package='herd_ros', executable=executable, name=executable, output='screen',
                    parameters=[str(config / f'{executable}.yaml'), *params, use_sim_time])

    return LaunchDescription([
        DeclareLaunchArgument('bag', default_value=str(share / 'bags' / 'cows_3x1h'),
                              description='rosbag2 of NavSatFix on /herd/<cow>/fix'),
        DeclareLaunchArgument('rate', default_value='10.0', description='replay speed-up'),
        DeclareLaunchArgument('use_sim_time', default_value='true',
                              description='follow the bag clock published by replay'),
        Node(package='herd_ros', executable='replay', name='replay', output='screen',
             parameters=[str(config / 'replay.yaml'),
                         {'bag': bag, 'rate': ParameterValue(rate, value_type=float),
                          'publish_clock': True}]),
        node('gps_ingest', herd, {'datum': DATUM}),
        node('estimator', herd, field, {'law': 'pairwise'}),
        node('controller', field, {'robots': ROBOTS, 'assignment': AGENTS, 'agents': AGENTS,
                                   'dt': DT, 'mode': 'herd_model', 'model_source': 'topic',
                                   'model_min_updates': 30, 'noise': True,
                                   'rate_hz': 1.0 / DT, 'safety_horizon_s': DT,
                                   'odom_timeout_s': 3 * DT}),
        node('fleet_sim', {'robots': ROBOTS, 'datum': DATUM, 'cmd_timeout_s': 1.5 * DT}),
    ])
