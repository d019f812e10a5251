"""`fleet_sim` node: N simulated robots (holonomic or unicycle) driven by body-frame Twists.

Subscribes ``/fleet/<robot>/cmd_vel`` (geometry_msgs/Twist, body frame, REP-103). Publishes
``/fleet/<robot>/odom`` (nav_msgs/Odometry: pose in ``frame_id``, twist in
``<robot>/base_link``), ``/fleet/poses`` (PoseArray in ``robots`` order),
``/fleet/<robot>/fix`` (NavSatFix about ``datum``, at ``fix_rate_hz``) and ``/diagnostics``.

The physics is :mod:`herd_ros.control.kinematics`; the node steps it on a timer of the node
clock (so ``use_sim_time`` works) with the clock time elapsed since the last step. A robot
whose last command is older than ``cmd_timeout_s`` (or that never got one) is stopped at
once — a watchdog cut, not a ramp — so it is still within ``cmd_timeout_s`` plus one step
after its controller went silent. The fence is a wall: a step that would cross it is not
taken (the robot stops, a fence contact is counted). Obstacles are not walls: overlaps with
them (and between robots) are counted as collisions and reported in ``/diagnostics``.
"""
from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseArray, Twist
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import NavSatFix, NavSatStatus

from herd_ros.control import kinematics as kin
from herd_ros.control.safety import Fence, Obstacles
from herd_ros.errors import HerdInputError
from herd_ros.ingest.geodesy import enu_to_geodetic
from herd_ros.model.model_file import check_agent_id
from herd_ros.nodes.ros_common import (OK, WARN, LiveParameters, ParameterError,
                                       declare_parameters, describe_remaining_parameters,
                                       diagnostic_array, diagnostic_status, exit_process,
                                       number_problem, run_node)
from herd_ros.params.fleet_sim import PARAMS as DEFAULTS


#: Periods of a clock jump fleet_sim integrates through; a longer jump restarts its grid.
MAX_CATCH_UP = 100


def yaw_to_quaternion(yaw: float):
    return 0.0, 0.0, float(np.sin(yaw / 2.0)), float(np.cos(yaw / 2.0))


class FleetSimConfig:
    """Validated fleet_sim parameters (raises :class:`ParameterError` naming the parameter)."""

    def __init__(self, p: dict):
        try:
            self.robots = [check_agent_id(r) for r in p['robots']]
        except HerdInputError as exc:
            raise ParameterError(f'robots: {exc}') from None
        if not self.robots or len(set(self.robots)) != len(self.robots):
            raise ParameterError('robots must be a non-empty list of distinct names')
        if p['kinematics'] not in kin.KINEMATICS:
            raise ParameterError(f'kinematics must be holonomic or unicycle, got '
                                 f'{p["kinematics"]!r}')
        self.kinematics = p['kinematics']
        for name in ('rate_hz', 'max_speed', 'max_accel', 'max_yaw_rate', 'cmd_timeout_s',
                     'fix_rate_hz', 'diagnostics_period_s'):
            value = float(p[name])
            if not (np.isfinite(value) and value > 0):
                raise ParameterError(f'{name} must be a positive number, got {p[name]!r}')
            setattr(self, name, value)
        for name in ('robot_radius', 'gps_noise_std'):
            value = float(p[name])
            if not (np.isfinite(value) and value >= 0):
                raise ParameterError(f'{name} must be ≥ 0, got {p[name]!r}')
            setattr(self, name, value)
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


class FleetSim(Node):
    def __init__(self):
        super().__init__('fleet_sim')
        self.cfg = cfg = FleetSimConfig(declare_parameters(self, DEFAULTS))
        n = len(cfg.robots)
        self.state = kin.FleetState.at_rest(cfg.initial_poses)
        self.command = np.zeros((n, 3))                  # v_x, v_y, ω (body frame)
        self.command_time = np.full(n, np.nan)           # node-clock seconds of the last command
        self.yaw_rate = np.zeros(n)                      # realised ω of the last step
        self.rng = np.random.default_rng(cfg.seed)
        self.collisions = np.zeros(n, dtype=np.int64)    # onsets of overlap (obstacles, robots)
        self.fence_contacts = np.zeros(n, dtype=np.int64)
        self.stale_events = np.zeros(n, dtype=np.int64)
        self._overlap = np.zeros(n, bool)
        self._was_stale = np.ones(n, bool)
        self.odom_pubs = [self.create_publisher(Odometry, f'/fleet/{r}/odom', 10)
                          for r in cfg.robots]
        self.fix_pubs = [self.create_publisher(NavSatFix, f'/fleet/{r}/fix', 10)
                         for r in cfg.robots]
        self.poses_pub = self.create_publisher(PoseArray, '/fleet/poses', 10)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        for k, r in enumerate(cfg.robots):
            self.create_subscription(Twist, f'/fleet/{r}/cmd_vel',
                                     lambda msg, k=k: self.on_cmd(k, msg), 10)
        self._last_step = None
        self._next_grid = None
        self._snapshots = []                             # (grid time, state, yaw rate)
        self._last_fix = -np.inf
        self._last_diag = -np.inf
        self.create_timer(1.0 / cfg.rate_hz, self.step)
        describe_remaining_parameters(self, 'not a fleet_sim parameter (ignored)')
        LiveParameters(self, self._validate_live, self._apply_live)
        self.get_logger().info(f'{n} {cfg.kinematics} robots at {cfg.rate_hz:g} Hz: '
                               f'{", ".join(cfg.robots)}')

    # -- live parameters (max_speed, max_accel, max_yaw_rate, cmd_timeout_s) --------------
    def _validate_live(self, name, value):
        return number_problem(value)

    def _apply_live(self, name, value):
        setattr(self.cfg, name, float(value))          # read at every step

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_cmd(self, k: int, msg: Twist):
        """A command takes effect when it arrives: the fleet is first advanced to now under
        the commands it had (a command is not applied back to the last step, nor held
        until the next one)."""
        now = self.now_s()
        self.integrate_to(now)
        self.command[k] = (msg.linear.x, msg.linear.y, msg.angular.z)
        self.command_time[k] = now

    def step(self):
        now = self.now_s()
        self.integrate_to(now)
        snapshots, self._snapshots = self._snapshots, []
        for t, state, yaw_rate in snapshots:
            self.publish(now, t, state, yaw_rate)

    def integrate_to(self, now: float):
        """Advance every robot to ``now`` under its current command, keeping its state at
        every multiple of the step period 1/rate_hz on the way: the poses are published at
        those grid times, stamped with them (with rate_hz = 2/Δt the grid holds every
        herd-clock tick k·Δt, so a robot is measured at the ticks its animal is)."""
        period = 1.0 / self.cfg.rate_hz
        if now <= 0.0:                  # sim time before the first /clock: nothing yet
            return
        if (self._last_step is None or now < self._last_step - 1e-9
                or now - self._next_grid > MAX_CATCH_UP * period):
            # the first call, time going backwards (a bag replayed again) or a jump (sim
            # time starting, a replay resumed): the grid restarts at now, the robots where
            # they are (stepping the gap one period at a time would stall the node)
            if self._last_step is not None:
                self.get_logger().warn(f'clock jumped from {self._last_step:.3f} to {now:.3f} s: '
                                       f'the robots hold their state across the jump')
            self._last_step = now
            self._next_grid = np.ceil(now / period - 1e-9) * period
        while self._next_grid <= now + 1e-9:
            self._advance_span(self._next_grid)
            self._snapshots.append((self._next_grid, self.state, self.yaw_rate.copy()))
            self._next_grid += period
        self._advance_span(now)

    def _advance_span(self, now: float):
        """Advance from the last integration time to ``now`` (zero command where stale: the
        watchdog)."""
        cfg = self.cfg
        if now <= self._last_step:
            return
        h = min(now - self._last_step, 5.0 / cfg.rate_hz)
        self._last_step = now
        with np.errstate(invalid='ignore'):
            stale = ~(now - self.command_time <= cfg.cmd_timeout_s)
        self.stale_events += stale & ~self._was_stale
        self._was_stale = stale
        cmd = np.where(stale[:, None], 0.0, self.command)
        if h > 0:
            self.advance(cmd, stale, h)

    def advance(self, cmd, stale, h):
        cfg, old = self.cfg, self.state
        if cfg.kinematics == 'holonomic':
            new = kin.step_holonomic(old, cmd[:, :2], cmd[:, 2], h, cfg.max_speed, cfg.max_accel,
                                     cfg.max_yaw_rate)
        else:
            new = kin.step_unicycle(old, cmd[:, 0], cmd[:, 2], h, cfg.max_speed, cfg.max_accel,
                                    cfg.max_yaw_rate)
        new.velocity[stale] = 0.0                        # watchdog: stale commands cut the drive
        new.positions[stale] = old.positions[stale]
        if cfg.fence is not None:
            t, _ = cfg.fence.first_crossing(old.positions, new.positions)
            blocked = np.isfinite(t)
            self.fence_contacts += blocked
            new.positions[blocked] = old.positions[blocked]
            new.velocity[blocked] = 0.0
        self.yaw_rate = kin.wrap_angle(new.yaw - old.yaw) / h
        self.state = new
        overlap = np.zeros(len(cfg.robots), bool)
        if len(cfg.obstacles):
            overlap |= cfg.obstacles.collisions(new.positions, cfg.robot_radius) > 0
        d = np.sqrt(((new.positions[:, None] - new.positions[None]) ** 2).sum(-1))
        np.fill_diagonal(d, np.inf)
        overlap |= (d < 2 * cfg.robot_radius).any(axis=1)
        self.collisions += overlap & ~self._overlap
        self._overlap = overlap

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
        cfg = self.cfg
        with np.errstate(invalid='ignore'):
            stale = ~(now - self.command_time <= cfg.cmd_timeout_s)
        statuses = []
        for k, robot in enumerate(cfg.robots):
            level = WARN if (stale[k] or self._overlap[k]) else OK
            message = ('colliding' if self._overlap[k] else
                       'commands stale: stopped' if stale[k] else 'ok')
            statuses.append(diagnostic_status(
                f'fleet_sim: {robot}', level, message,
                {'collisions': int(self.collisions[k]),
                 'fence_contacts': int(self.fence_contacts[k]),
                 'stale_command_events': int(self.stale_events[k]),
                 'command_stale': bool(stale[k]),
                 'x': float(self.state.positions[k, 0]), 'y': float(self.state.positions[k, 1])},
                hardware_id=robot))
        statuses.append(diagnostic_status(
            'fleet_sim', OK, f'{len(cfg.robots)} robots',
            {'collisions_total': int(self.collisions.sum()),
             'fence_contacts_total': int(self.fence_contacts.sum()),
             'robots_stale': int(stale.sum())}))
        self.diag_pub.publish(diagnostic_array(self, statuses))


def main(args=None):
    exit_process(run_node(FleetSim, args=args))


if __name__ == '__main__':
    main()
