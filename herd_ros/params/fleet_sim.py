"""Parameters of the ``fleet_sim`` node: the one table its ROS parameters, their checks,
``config/fleet_sim.yaml`` and the documentation come from (:mod:`herd_ros.params`)."""
from herd_ros.params import NodeTable, Param

HEADER = ('# fleet_sim: N simulated robots driven by body-frame Twists on '
          '/fleet/<robot>/cmd_vel.\n'
          '# Publishes /fleet/<robot>/odom, /fleet/poses, /fleet/<robot>/fix and '
          '/diagnostics.\n'
          '# Every parameter below is shown with its default. Run:\n'
          '#   ros2 run herd_ros fleet_sim --ros-args --params-file config/fleet_sim.yaml\n')

PARAMS = {
    'robots': Param(
        ['robot_1', 'robot_2', 'robot_3'],
        'robot names, in the order of /fleet/poses',
        doc=('Robot names, in the order of /fleet/poses. Each becomes part of '
             'its topic names,\n'
             'so letters, digits and underscores only, starting with a letter.')),
    'kinematics': Param(
        'holonomic',
        'holonomic (linear.x/y, angular.z) or unicycle (linear.x, angular.z)',
        choices=('holonomic', 'unicycle'),
        doc=('\n'
             'holonomic: omnidirectional, obeys linear.x, linear.y and '
             'angular.z.\n'
             'unicycle: differential drive, obeys linear.x and angular.z '
             '(linear.y is ignored).')),
    'rate_hz': Param(
        20.0,
        'simulation step rate (Hz, node clock)',
        range=(1e-06, 1000.0),
        doc=('\n'
             'Simulation step rate (Hz) on the node clock (use_sim_time: true '
             'follows /clock).\n'
             'Each step integrates the time actually elapsed on that clock.')),
    'initial_poses': Param(
        [],
        ('initial x, y, yaw per robot (m, m, rad), flattened; empty = on the x '
         'axis 2 m apart'),
        example=[0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 4.0, 0.0, 0.0],
        commented=True,
        doc=('\n'
             'Initial poses x, y, yaw (m, m, rad CCW from east) for each robot, '
             'flattened.\n'
             'Empty: robots on the x axis 2 m apart, facing east.\n'
             'ROS parameter files cannot hold an empty list, so the default is '
             'left unset:')),
    'max_speed': Param(
        1.0,
        'speed limit (m/s)',
        range=(1e-06, 100.0),
        live=True,
        doc=('\n'
             'Speed limit (m/s), acceleration limit (m/s², on the velocity '
             'vector; on the forward\n'
             'speed for unicycles) and yaw-rate limit (rad/s) of every robot.')),
    'max_accel': Param(
        2.0,
        'acceleration limit (m/s²)',
        range=(1e-06, 1000.0),
        live=True),
    'max_yaw_rate': Param(
        2.0,
        'yaw-rate limit (rad/s)',
        range=(1e-06, 1000.0),
        live=True),
    'cmd_timeout_s': Param(
        1.0,
        'a robot whose last command is older (s) is stopped',
        range=(1e-06, 1000000.0),
        live=True,
        doc=('\n'
             'A robot whose last command is older than this (s), or that never '
             'got one, is stopped\n'
             'at once (a watchdog cut, not a ramp). Keep it >= a few controller '
             'periods.')),
    'obstacles': Param(
        [],
        'circular obstacles x, y, r (m), flattened (collisions counted)',
        example=[10.0, 5.0, 2.0],
        commented=True,
        doc=('\n'
             'Circular obstacles x, y, r (m), flattened. They are not walls: '
             'overlaps are counted as\n'
             'collisions in /diagnostics (robot_radius is added to r). Default: '
             'none.')),
    'fence': Param(
        [],
        'fence polygon x1, y1, x2, y2, ... (m, map): a wall',
        example=[-50.0, -50.0, 50.0, -50.0, 50.0, 50.0, -50.0, 50.0],
        commented=True,
        doc=('\n'
             'Fence polygon x1, y1, x2, y2, ... (m, map frame), closed '
             'implicitly. It is a wall: a\n'
             'step that would cross it is not taken and counted as a fence '
             'contact. Default: none.')),
    'robot_radius': Param(
        0.3,
        'radius (m) of each robot for collision counting',
        range=(0.0, 100.0),
        doc=('\n'
             "Radius (m) of each robot's disc for collision counting (robots "
             'and obstacles).')),
    'datum': Param(
        [27.0153, -108.7937, 0.0],
        'datum [lat, lon, alt] of the map frame for the simulated GPS',
        doc=('\n'
             'Datum [lat, lon, alt] (deg, deg, m) of the map frame for the '
             'simulated GPS\n'
             '(/fleet/<robot>/fix, exact WGS84). Use the same datum as '
             'gps_ingest to feed robots\n'
             'through it like animals.')),
    'frame_id': Param(
        'map',
        'frame of odometry and /fleet/poses',
        doc=('\n'
             'Frame of odometry poses and of /fleet/poses.')),
    'gps_noise_std': Param(
        0.0,
        'std (m) of the simulated GPS noise',
        range=(0.0, 10000.0),
        doc=('\n'
             'Standard deviation (m) of the simulated GPS noise on east and '
             'north (0: exact).\n'
             "The fix's position_covariance says the same (DIAGONAL_KNOWN when "
             '> 0).')),
    'fix_rate_hz': Param(
        1.0,
        'rate (Hz) of the simulated fixes',
        range=(1e-06, 1000.0),
        doc=('\n'
             'Rate (Hz) of the simulated fixes (collars and many GPS receivers '
             'report at 1 Hz).')),
    'seed': Param(
        0,
        'seed of the GPS noise generator',
        range=(0, 2147483647),
        doc=('\n'
             'Seed of the GPS noise generator.')),
    'diagnostics_period_s': Param(
        1.0,
        'period (s) of /diagnostics',
        range=(0.001, 3600.0),
        doc=('\n'
             'Period (s) of /diagnostics (collisions, fence contacts, stale '
             'commands per robot).')),
}

TABLE = NodeTable('fleet_sim', HEADER, PARAMS)


class FleetSimConfig:
    """fleet_sim parameters (values checked against :data:`PARAMS`) made into what the
    node runs with; raises :class:`~herd_ros.params.ParameterError` naming what is wrong
    beyond the table's checks."""

    def __init__(self, p: dict):
        import numpy as np

        from herd_ros.control.safety import Fence, Obstacles
        from herd_ros.errors import HerdInputError
        from herd_ros.params import ParameterError, distinct_ids
        self.robots = distinct_ids(p, 'robots', 'names')
        # types, ranges (> 0, >= 0) and choices: checked against the table
        for name in ('kinematics', 'rate_hz', 'max_speed', 'max_accel', 'max_yaw_rate',
                     'cmd_timeout_s', 'fix_rate_hz', 'diagnostics_period_s', 'robot_radius',
                     'gps_noise_std'):
            setattr(self, name, p[name])
        n = len(self.robots)
        poses = np.asarray(list(p['initial_poses']), dtype=float)
        if poses.size == 0:
            poses = np.column_stack([2.0 * np.arange(n), np.zeros(n), np.zeros(n)])
        elif poses.size != 3 * n or not np.isfinite(poses).all():
            raise ParameterError(f'initial_poses needs x, y, yaw for each of the {n} robots '
                                 f'({3 * n} finite numbers), got {poses.size}')
        self.initial_poses = poses.reshape(n, 3)
        try:
            self.obstacles = Obstacles.from_flat(p['obstacles'])
            self.fence = Fence.from_flat(p['fence'])
        except HerdInputError as exc:
            raise ParameterError(str(exc)) from None
        if self.fence is not None and not self.fence.contains(self.initial_poses[:, :2]).all():
            raise ParameterError('initial_poses: every robot must start inside the fence')
        datum = [float(x) for x in p['datum']]
        if len(datum) not in (2, 3) or not np.isfinite(datum).all() or abs(datum[0]) > 90:
            raise ParameterError(f'datum must be [lat, lon] or [lat, lon, alt] in degrees, '
                                 f'got {p["datum"]!r}')
        self.datum = datum + [0.0] * (3 - len(datum))
        self.frame_id = str(p['frame_id'])
        self.seed = int(p['seed'])
