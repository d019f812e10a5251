"""`controller` node: drive the fleet's robots with a control mode, through the safety layer.

Subscribes ``/fleet/<robot>/odom`` for its own ``robots`` and the ``other_robots`` it only
watches (they count as neighbours); publishes ``/fleet/<robot>/cmd_vel`` (Twist, body frame)
for its own robots only, at ``rate_hz`` on the node clock, and ``/diagnostics``.

Each tick: odometry -> :class:`FleetObservation` -> the mode's policy ``command(state)``
(world velocities) -> :func:`herd_ros.control.safety.safe_velocity` (speed, obstacles,
fence) -> body-frame Twist (:mod:`herd_ros.control.kinematics`). A robot whose odometry is
older than ``odom_timeout_s`` (or never came) gets an explicit zero Twist on that tick. No
robot is driven before every owned robot has reported once, or ``startup_wait_s`` after the
first did (:class:`~herd_ros.control.fleet_start.StartGate`).

Modes are a seam: :data:`POLICIES` maps a mode name to a class with
``from_node(node) -> policy`` (declares and reads its own parameters) and
``command(state) -> (R, 2)`` world velocities for every observed robot. ``herd_model``
(:mod:`herd_ros.nodes.herd_model_mode`), ``flocking`` (:mod:`herd_ros.nodes.flocking_mode`),
``imitation`` (:mod:`herd_ros.nodes.imitation_mode`) and ``herding``
(:mod:`herd_ros.nodes.herding_mode`) sit side by side, each the shell of its core under
:mod:`herd_ros.control`, :mod:`herd_ros.flocking`, :mod:`herd_ros.imitation` or
:mod:`herd_ros.herding`.
"""
from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.node import Node

from herd_ros.control import kinematics as kin
from herd_ros.control.fleet_observation import FleetObservation, odometry_age
from herd_ros.control.fleet_start import StartGate
from herd_ros.control.safety import Fence, Obstacles, safe_velocity, stale_mask
from herd_ros.errors import HerdInputError
from herd_ros.model.model_file import check_agent_id
from herd_ros.nodes.flocking_mode import FlockingPolicy
from herd_ros.nodes.herd_model_mode import HerdModelPolicy
from herd_ros.nodes.herding_mode import HerdingPolicy
from herd_ros.nodes.imitation_mode import ImitationPolicyMode
from herd_ros.nodes.ros_common import (LATEST_ONLY, OK, WARN, LiveParameters, ParameterError,
                                       declare_parameters, describe_remaining_parameters,
                                       diagnostic_array, diagnostic_status, exit_process,
                                       run_node)
from herd_ros.params.controller import COMMON as DEFAULTS


#: Mode name -> policy class (``from_node(node)``, ``command(state)``).
POLICIES = {'herd_model': HerdModelPolicy, 'flocking': FlockingPolicy,
            'imitation': ImitationPolicyMode, 'herding': HerdingPolicy}


def yaw_from_quaternion(q) -> float:
    """Yaw (rad, CCW from east) of a geometry_msgs/Quaternion (ZYX convention)."""
    return float(np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z)))


class Controller(Node):
    """The ``controller`` node (module docstring)."""
    def __init__(self):
        super().__init__('controller', automatically_declare_parameters_from_overrides=True)
        p = declare_parameters(self, DEFAULTS)
        self._configure(p)
        n = len(self.all_robots)
        self.positions = np.full((n, 2), np.nan)
        self.yaw = np.full(n, np.nan)
        self.velocity = np.zeros((n, 2))
        self.odom_time = np.full(n, np.nan)
        self.odom_stamp = np.full(n, np.nan)    # the odometry's own stamps (s)
        self.last_command = np.zeros((n, 2))
        self.counts = {key: np.zeros(n, dtype=np.int64)
                       for key in ('speed_limited', 'obstacle_limited', 'fence_limited',
                                   'stale_ticks')}
        for k, robot in enumerate(self.all_robots):
            self.create_subscription(Odometry, f'/fleet/{robot}/odom',
                                     lambda msg, k=k: self.on_odom(k, msg), LATEST_ONLY)
        self.cmd_pubs = [self.create_publisher(Twist, f'/fleet/{r}/cmd_vel', 10)
                         for r in self.robots]
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.policy = POLICIES[self.mode].from_node(self)
        self.start_gate = StartGate(self.startup_wait_s)
        self._last_diag = -np.inf
        self.timer = self.create_timer(self.period, self.tick)
        describe_remaining_parameters(self, {
            'model.': 'the model (model file of herd-ros fit or the estimator, or an '
                      'imitation policy file; keys in doc/formats.md)',
            'flocking.': 'flocking gain or setting (config/flocking.yaml)',
            '': 'not a controller parameter (ignored)'})
        LiveParameters(self, self._validate_live, self._apply_live)
        self.get_logger().info(f'mode {self.mode}: driving {", ".join(self.robots)} at '
                               f'{1 / self.period:g} Hz; {self.policy.status}')

    def _configure(self, p):
        try:
            self.robots = [check_agent_id(r) for r in p['robots']]
            self.other_robots = [check_agent_id(r) for r in p['other_robots']]
            self.fence = Fence.from_flat(p['fence'])
            self.obstacles = Obstacles.from_flat(p['obstacles'])
        except HerdInputError as exc:
            raise ParameterError(str(exc)) from None
        self.all_robots = self.robots + self.other_robots
        if not self.robots or len(set(self.all_robots)) != len(self.all_robots):
            raise ParameterError('robots must be non-empty and robots + other_robots distinct')
        # types, ranges and choices: checked against the table (herd_ros/params/controller.py)
        for name in ('mode', 'kinematics', 'rate_hz', 'max_speed', 'heading_gain',
                     'max_yaw_rate', 'odom_timeout_s', 'diagnostics_period_s',
                     'safety_horizon_s', 'fence_margin', 'startup_wait_s'):
            setattr(self, name, p[name])
        self.period = 1.0 / self.rate_hz
        self.horizon = max(self.safety_horizon_s, self.period)
        self.owned = np.array([r in self.robots for r in self.all_robots])

    # -- live parameters (rate_hz, max_speed, fence_margin, odom_timeout_s) ---------------
    def _validate_live(self, name, value):
        return None        # the table's range says all (rate_hz, max_speed > 0, ...)

    def _apply_live(self, name, value):
        setattr(self, name, float(value))
        if name == 'rate_hz':
            self.period = 1.0 / self.rate_hz
            self.horizon = max(self.safety_horizon_s, self.period)
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = self.create_timer(self.period, self.tick)

    def now_s(self) -> float:
        """The node clock (s; simulated time with use_sim_time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def on_odom(self, k: int, msg: Odometry):
        """Take robot ``k``'s odometry: position, yaw, world velocity, time."""
        pose, twist = msg.pose.pose, msg.twist.twist
        self.positions[k] = (pose.position.x, pose.position.y)
        self.yaw[k] = yaw_from_quaternion(pose.orientation)
        self.velocity[k] = kin.body_to_world(np.array([twist.linear.x, twist.linear.y]),
                                             self.yaw[k])
        self.odom_time[k] = self.now_s()
        self.odom_stamp[k] = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9

    def tick(self):
        """One control period: the mode's velocities through the safety layer to Twists."""
        now = self.now_s()
        if not self.start_gate.open:
            if not self.start_gate.update(self.odom_time, self.owned, now):
                self._hold_fleet(now)
                return
            missing = [self.all_robots[k] for k in self.start_gate.missing_at_start]
            if missing:
                self.get_logger().warn(f'starting without {", ".join(missing)}: no odometry '
                                       f'within startup_wait_s ({self.startup_wait_s:g} s) '
                                       f'of the first robot\'s')
        active = ~stale_mask(self.odom_time, now, self.odom_timeout_s)
        last = np.where(self.owned[:, None], self.last_command, self.velocity)
        state = FleetObservation(list(self.all_robots), self.owned, self.positions.copy(),
                                 self.yaw.copy(), self.velocity.copy(), active, last,
                                 self.period, now,
                                 odometry_age(now, self.odom_stamp, self.odom_time,
                                              self.odom_timeout_s))
        desired = np.asarray(self.policy.command(state), dtype=float).reshape(-1, 2)
        go = self.owned & active & np.isfinite(desired).all(-1)
        world = np.zeros_like(desired)
        forward = np.zeros(len(desired))
        lateral = np.zeros(len(desired))
        omega = np.zeros(len(desired))
        if go.any():
            world[go], report = safe_velocity(self.positions[go], desired[go], self.horizon,
                                              self.max_speed, self.fence, self.obstacles,
                                              self.fence_margin)
            for key, mask in report.items():
                self.counts[key][go] += mask
            forward[go], lateral[go], omega[go] = self.to_twist(world[go], go)
        self.counts['stale_ticks'] += self.owned & ~active
        self.last_command = np.where(go[:, None], world, 0.0)
        for i, k in enumerate(np.flatnonzero(self.owned)):
            msg = Twist()
            msg.linear.x, msg.linear.y = float(forward[k]), float(lateral[k])
            msg.angular.z = float(omega[k])
            self.cmd_pubs[i].publish(msg)
        if now - self._last_diag >= self.diagnostics_period_s - 1e-9:
            self._last_diag = now
            self.publish_diagnostics(active, world)

    def _hold_fleet(self, now: float):
        """Before the start (:class:`StartGate`): a zero Twist to every owned robot, and the
        diagnostics say whose odometry is awaited."""
        for pub in self.cmd_pubs:
            pub.publish(Twist())
        if now - self._last_diag >= self.diagnostics_period_s - 1e-9:
            self._last_diag = now
            waiting = [r for k, r in enumerate(self.all_robots)
                       if self.owned[k] and not np.isfinite(self.odom_time[k])]
            self.diag_pub.publish(diagnostic_array(self, [diagnostic_status(
                'controller', WARN, f'mode {self.mode}: {getattr(self.policy, "status", "")}; '
                f'waiting for the odometry of {", ".join(waiting)} before driving the fleet',
                {'robots': len(self.robots), 'waiting_for': len(waiting)})]))

    def to_twist(self, world: np.ndarray, rows: np.ndarray):
        """Body-frame commands for ``world`` velocities of robots ``rows`` (a unicycle drives
        only along its heading, so its realised path is checked against the fence again)."""
        yaw = self.yaw[rows]
        forward, lateral, omega = kin.twist_from_world_velocity(
            world, yaw, self.kinematics, self.heading_gain, self.max_yaw_rate)
        if self.kinematics == 'unicycle':
            # only shorten (never turn) the realised path v·[cos ψ, sin ψ]: still along ψ
            p = self.positions[rows]
            realised = kin.realised_world_velocity(forward, lateral, yaw, self.kinematics)
            if self.fence is not None:
                realised, _ = self.fence.scale_to_stay_inside(p, realised, self.horizon,
                                                              self.fence_margin)
            if len(self.obstacles):
                realised = self.obstacles.shorten(p, realised, self.horizon, self.fence_margin)
            forward = np.maximum((realised * kin.heading_vector(yaw)).sum(-1), 0.0)
        return forward, lateral, omega

    def publish_diagnostics(self, active, world):
        """Per robot its counters and speed, and the mode's status, on /diagnostics."""
        statuses = []
        # herd_model: the time (node clock, s) each robot's law took over from its wait
        since = getattr(self.policy, 'law_since', None)
        if since is not None and len(since) != len(self.all_robots):
            since = None
        for k, robot in enumerate(self.all_robots):
            if not self.owned[k]:
                continue
            level = OK if active[k] else WARN
            law = {} if since is None else {'law_since': float(since[k])}
            statuses.append(diagnostic_status(
                f'controller: {robot}', level,
                'ok' if active[k] else 'odometry stale: commanding zero',
                {'speed': float(np.hypot(*world[k])),
                 **{key: int(c[k]) for key, c in self.counts.items()}, **law},
                hardware_id=robot))
        statuses.append(diagnostic_status(
            'controller', OK if getattr(self.policy, 'follower', True) is not None else WARN,
            f'mode {self.mode}: {getattr(self.policy, "status", "")}',
            {'robots': len(self.robots), 'watched_robots': len(self.other_robots),
             'model_updates': getattr(self.policy, 'updates', 0)}))
        self.diag_pub.publish(diagnostic_array(self, statuses))


def main(args=None):
    """Run the node (``ros2 run herd_ros NODE``); exits with its status."""
    exit_process(run_node(Controller, args=args))


if __name__ == '__main__':
    main()
