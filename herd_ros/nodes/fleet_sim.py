"""`fleet_sim` node: N simulated robots (holonomic or unicycle) driven by body-frame Twists.

Subscribes ``/fleet/<robot>/cmd_vel`` (geometry_msgs/Twist, body frame, REP-103). Publishes
``/fleet/<robot>/odom`` (nav_msgs/Odometry: pose in ``frame_id``, twist in
``<robot>/base_link``), ``/fleet/poses`` (PoseArray in ``robots`` order),
``/fleet/<robot>/fix`` (NavSatFix about ``datum``, at ``fix_rate_hz``) and ``/diagnostics``.

The fleet is :class:`~herd_ros.simulation.fleet.FleetSimulator` (no ROS: kinematics,
command watchdog, fence as a wall, collision counts); the node steps it on a timer of the
node clock (so ``use_sim_time`` works), publishes the states it kept at every step period
(stamped with them), the noisy fixes and the counts in ``/diagnostics``.
"""
from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseArray, Twist
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import NavSatFix, NavSatStatus

from herd_ros.ingest.geodesy import enu_to_geodetic
from herd_ros.nodes.ros_common import (LATEST_ONLY, OK, WARN, LiveParameters,
                                       declare_parameters,
                                       describe_remaining_parameters, diagnostic_array,
                                       diagnostic_status, exit_process, run_node)
from herd_ros.params.fleet_sim import PARAMS as DEFAULTS, FleetSimConfig
from herd_ros.simulation.fleet import FleetSimulator


def yaw_to_quaternion(yaw: float):
    """(x, y, z, w) of a rotation by ``yaw`` about z."""
    return 0.0, 0.0, float(np.sin(yaw / 2.0)), float(np.cos(yaw / 2.0))


class FleetSim(Node):
    """The ``fleet_sim`` node (module docstring)."""
    def __init__(self):
        super().__init__('fleet_sim')
        self.cfg = cfg = FleetSimConfig(declare_parameters(self, DEFAULTS))
        n = len(cfg.robots)
        self.fleet = FleetSimulator(cfg)
        self.rng = np.random.default_rng(cfg.seed)
        self.odom_pubs = [self.create_publisher(Odometry, f'/fleet/{r}/odom', 10)
                          for r in cfg.robots]
        self.fix_pubs = [self.create_publisher(NavSatFix, f'/fleet/{r}/fix', 10)
                         for r in cfg.robots]
        self.poses_pub = self.create_publisher(PoseArray, '/fleet/poses', 10)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        for k, r in enumerate(cfg.robots):
            self.create_subscription(Twist, f'/fleet/{r}/cmd_vel',
                                     lambda msg, k=k: self.on_cmd(k, msg), LATEST_ONLY)
        self._last_fix = -np.inf
        self._last_diag = -np.inf
        self.create_timer(1.0 / cfg.rate_hz, self.step)
        describe_remaining_parameters(self, 'not a fleet_sim parameter (ignored)')
        LiveParameters(self, self._validate_live, self._apply_live)
        self.get_logger().info(f'{n} {cfg.kinematics} robots at {cfg.rate_hz:g} Hz: '
                               f'{", ".join(cfg.robots)}')

    # -- live parameters (max_speed, max_accel, max_yaw_rate, cmd_timeout_s) --------------
    def _validate_live(self, name, value):
        return None        # the table's range says all (> 0)

    def _apply_live(self, name, value):
        setattr(self.cfg, name, float(value))          # read at every step

    def now_s(self) -> float:
        """The node clock (s; simulated time with use_sim_time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def on_cmd(self, k: int, msg: Twist):
        """A command takes effect when it arrives: the fleet is first advanced to now under
        the commands it had (a command is not applied back to the last step, nor held
        until the next one)."""
        self.fleet.set_command(k, self.now_s(), (msg.linear.x, msg.linear.y, msg.angular.z))
        self._log_fleet()

    def step(self):
        """One step: integrate the fleet to now and publish odometry, poses and fixes."""
        now = self.now_s()
        self.fleet.integrate_to(now)
        self._log_fleet()
        for t, state, yaw_rate in self.fleet.take_snapshots():
            self.publish(now, t, state, yaw_rate)

    def _log_fleet(self):
        for line in self.fleet.log:
            self.get_logger().warn(line)
        self.fleet.log.clear()

    def publish(self, now: float, t: float, s, yaw_rate):
        """The poses of state ``s`` at grid time ``t`` (stamped ``t``); fixes and
        diagnostics on their own periods."""
        cfg = self.cfg
        stamp = Time(nanoseconds=int(round(t * 1e9)),
                     clock_type=self.get_clock().clock_type).to_msg()
        body = s.body_velocity
        poses = PoseArray()
        poses.header.stamp = stamp
        poses.header.frame_id = cfg.frame_id
        for k, robot in enumerate(cfg.robots):
            pose = Pose()
            pose.position.x, pose.position.y = float(s.positions[k, 0]), float(s.positions[k, 1])
            q = yaw_to_quaternion(s.yaw[k])
            (pose.orientation.x, pose.orientation.y, pose.orientation.z,
             pose.orientation.w) = q
            poses.poses.append(pose)
            odom = Odometry()
            odom.header.stamp = stamp
            odom.header.frame_id = cfg.frame_id
            odom.child_frame_id = f'{robot}/base_link'
            odom.pose.pose = pose
            odom.twist.twist.linear.x = float(body[k, 0])
            odom.twist.twist.linear.y = float(body[k, 1])
            odom.twist.twist.angular.z = float(yaw_rate[k])
            self.odom_pubs[k].publish(odom)
        self.poses_pub.publish(poses)
        if now - self._last_fix >= 1.0 / cfg.fix_rate_hz - 1e-9:
            self._last_fix = now
            self.publish_fixes(stamp, s)
        if now - self._last_diag >= cfg.diagnostics_period_s - 1e-9:
            self._last_diag = now
            self.publish_diagnostics(now)

    def publish_fixes(self, stamp, state):
        """Publish each robot's simulated GPS fix (with the configured noise)."""
        cfg = self.cfg
        noise = self.rng.normal(0.0, cfg.gps_noise_std, size=state.positions.shape) \
            if cfg.gps_noise_std > 0 else 0.0
        e, n = (state.positions + noise).T
        lat, lon, alt = enu_to_geodetic(e, n, np.zeros_like(e), *cfg.datum)
        var = cfg.gps_noise_std ** 2
        for k, robot in enumerate(cfg.robots):
            fix = NavSatFix()
            fix.header.stamp = stamp
            fix.header.frame_id = f'{robot}/gps'
            fix.status.status = NavSatStatus.STATUS_FIX
            fix.status.service = NavSatStatus.SERVICE_GPS
            fix.latitude, fix.longitude, fix.altitude = float(lat[k]), float(lon[k]), float(alt[k])
            fix.position_covariance = [var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, 4.0 * var]
            fix.position_covariance_type = (NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN if var > 0
                                            else NavSatFix.COVARIANCE_TYPE_UNKNOWN)
            self.fix_pubs[k].publish(fix)

    def publish_diagnostics(self, now: float):
        """Per robot its collisions, fence contacts and stale commands on /diagnostics."""
        cfg, fleet = self.cfg, self.fleet
        stale = fleet.stale(now)
        statuses = []
        for k, robot in enumerate(cfg.robots):
            level = WARN if (stale[k] or fleet.overlap[k]) else OK
            message = ('colliding' if fleet.overlap[k] else
                       'commands stale: stopped' if stale[k] else 'ok')
            statuses.append(diagnostic_status(
                f'fleet_sim: {robot}', level, message,
                {'collisions': int(fleet.collisions[k]),
                 'fence_contacts': int(fleet.fence_contacts[k]),
                 'stale_command_events': int(fleet.stale_events[k]),
                 'command_stale': bool(stale[k]),
                 'x': float(fleet.state.positions[k, 0]), 'y': float(fleet.state.positions[k, 1])},
                hardware_id=robot))
        statuses.append(diagnostic_status(
            'fleet_sim', OK, f'{len(cfg.robots)} robots',
            {'collisions_total': int(fleet.collisions.sum()),
             'fence_contacts_total': int(fleet.fence_contacts.sum()),
             'robots_stale': int(stale.sum())}))
        self.diag_pub.publish(diagnostic_array(self, statuses))


def main(args=None):
    """Run the node (``ros2 run herd_ros NODE``); exits with its status."""
    exit_process(run_node(FleetSim, args=args))


if __name__ == '__main__':
    main()
