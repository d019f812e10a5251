"""`controller` node: drive the fleet's robots with a control mode, through the safety layer.

Subscribes ``/fleet/<robot>/odom`` for its own ``robots`` and the ``other_robots`` it only
watches (they count as neighbours); publishes ``/fleet/<robot>/cmd_vel`` (Twist, body frame)
for its own robots only, at ``rate_hz`` on the node clock, and ``/diagnostics``.

Each tick: odometry -> :class:`FleetObservation` -> the mode's policy ``command(state)``
(world velocities) -> :func:`herd_ros.control.safety.safe_velocity` (speed, obstacles,
fence) -> body-frame Twist (:mod:`herd_ros.control.kinematics`). A robot whose odometry is
older than ``odom_timeout_s`` (or never came) gets an explicit zero Twist on that tick.

Modes are a seam: :data:`POLICIES` maps a mode name to a class with
``from_node(node) -> policy`` (declares and reads its own parameters) and
``command(state) -> (R, 2)`` world velocities for every observed robot. ``herd_model`` is
implemented here; ``flocking`` (:mod:`herd_ros.nodes.flocking_mode`) and ``imitation``
(:mod:`herd_ros.nodes.imitation_mode`) plug in the same way.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from herd_ros.control import kinematics as kin
from herd_ros.control.herd_follower import (HerdClockHold, HerdFollower, follower_for,
                                            model_from_parameter_matrix,
                                            shared_model_from_parameter_matrix)
from herd_ros.control.safety import Fence, Obstacles, safe_velocity, stale_mask
from herd_ros.errors import HerdInputError
from herd_ros.model.any_model import any_model_from_dict
from herd_ros.model.model_file import check_agent_id
from herd_ros.model.rbf_field import FieldGrid
from herd_ros.nodes.flocking_mode import FlockingPolicy
from herd_ros.nodes.imitation_mode import ImitationPolicyMode
from herd_ros.nodes.ros_common import (OK, WARN, LiveParameters, ParameterError,
                                       declare_parameters, describe_remaining_parameters,
                                       diagnostic_array, diagnostic_status, exit_process,
                                       number_problem, run_node)
from herd_ros.params.controller import COMMON as DEFAULTS, HERD_MODEL as HERD_MODEL_DEFAULTS


#: The controller's rule for a learned damping a (see :func:`damping_check`).
DAMPING_RULE = ('|a| >= 1 is refused: the law is unstable (speeds grow without bound); '
                '-1 < a < 0 is followed with a warning: the velocity reverses sign every step, '
                'which no animal does, but a fit on positions with GPS noise at a coarse '
                'clock learns it (differenced noise is anti-correlated), and it is the best '
                'one-step law for that data')


def damping_check(dampings, agents) -> tuple[str | None, str | None]:
    """(refusal, warning) for a model's dampings under :data:`DAMPING_RULE`.

    The velocity recursion v(t+1) = a·v(t) + ... is stable only for |a| < 1 and decays
    without oscillating only for 0 <= a < 1.
    """
    a = np.asarray(dampings, dtype=float)
    unstable = ~(np.abs(a) < 1.0)                   # NaN counts as unstable
    if unstable.any():
        k = int(np.argmax(unstable))
        return (f'damping {a[k]:.3f} of {agents[k]} makes the law unstable (|a| >= 1)'
                + (f'; {int(unstable.sum())} agents in all' if unstable.sum() > 1 else ''),
                None)
    negative = a < 0.0
    if negative.any():
        names = ', '.join(f'{agents[k]} {a[k]:.3f}' for k in np.flatnonzero(negative)[:5])
        return None, (f'negative damping ({names}'
                      + (', ...' if negative.sum() > 5 else '') + '): the law reverses those '
                      'velocities every step (usually position noise at a coarse clock); '
                      'following it')
    return None, None


@dataclass
class FleetObservation:
    """What a policy sees at a tick; arrays over the R observed robots (own first).

    positions (R, 2) m and yaw (R,) rad in the map frame (NaN until the first odometry),
    velocity (R, 2) m/s measured in the world frame, active (R,) fresh odometry,
    owned (R,) commanded by this controller, last_command (R, 2) world velocity issued
    last tick after the safety layer (measured velocity for robots not owned), period h (s),
    time (s, node clock).
    """

    robots: list[str]
    owned: np.ndarray
    positions: np.ndarray
    yaw: np.ndarray
    velocity: np.ndarray
    active: np.ndarray
    last_command: np.ndarray
    period: float
    time: float


class HerdModelPolicy:
    """Mode ``herd_model``: each robot follows its assigned animal's learned law.

    Model from the ``model.*`` parameters (``--params-file model.yaml``) or, with
    ``model_source: topic``, live from ``/herd/model/params`` (see
    :func:`~herd_ros.control.herd_follower.model_from_parameter_matrix`).
    """

    def __init__(self, node: 'Controller', p: dict):
        self.node = node
        self.robots = node.all_robots
        self.noise = bool(p['noise'])
        self.seed = int(p['seed'])
        self.assignment_given = [str(a) for a in p['assignment']] + \
            [str(a) for a in p['other_assignment']]
        self.follower: HerdFollower | None = None
        self.updates = 0
        self.status = 'waiting for a model'
        self.source = p['model_source']
        self.min_updates = int(p['model_min_updates'])
        self.received = 0
        self.refused_since_adopted = 0
        if self.source == 'file':
            model = self._model_from_parameters()
            problem, warning = damping_check(model.damping, list(model.agents))
            if problem:
                raise ParameterError(f'model file refused: {problem}')
            if warning:
                node.get_logger().warning(warning)
            self.set_model(model)
        elif self.source == 'topic':
            self._check_topic_parameters(p)
            self.noise_cov = None
            node.create_subscription(Float64MultiArray, '/herd/model/params',
                                     self.on_params, 10)
            node.create_subscription(Float64MultiArray, '/herd/model/noise',
                                     self.on_noise, 10)
        else:
            raise ParameterError(f'model_source must be file or topic, got {self.source!r}')

    @classmethod
    def from_node(cls, node: 'Controller') -> 'HerdModelPolicy':
        return cls(node, declare_parameters(node, HERD_MODEL_DEFAULTS))

    # -- model sources ------------------------------------------------------------------
    def _model_from_parameters(self):
        flat = {k: v.value for k, v in self.node.get_parameters_by_prefix('model').items()}
        if 'agents' not in flat:
            raise ParameterError('model_source is file but no model.* parameters were given: '
                                 'pass the model file with --ros-args --params-file model.yaml')
        body: dict = {}
        for key, value in flat.items():
            *path, leaf = key.split('.')
            node = body
            for part in path:
                node = node.setdefault(part, {})
            node[leaf] = value
        try:
            return any_model_from_dict(body, source='parameters model.*')
        except HerdInputError as exc:
            raise ParameterError(str(exc)) from None

    def _check_topic_parameters(self, p):
        try:
            self.agents = [check_agent_id(a) for a in p['agents']]
            grid = [int(v) for v in p['field_grid']]
            bounds = tuple(float(v) for v in p['field_bounds'])
            if len(grid) != 2 or len(bounds) != 4:
                raise HerdInputError('field_grid needs [nx, ny] and field_bounds '
                                     '[xmin, xmax, ymin, ymax]')
            self.grid = FieldGrid(grid[0], grid[1], bounds)
        except HerdInputError as exc:
            raise ParameterError(str(exc)) from None
        if len(self.agents) < 2:
            raise ParameterError('model_source topic needs agents (the estimator\'s agents, '
                                 'in its order, at least two)')
        self.dt = float(p['dt'])
        if not self.dt > 0:
            raise ParameterError(f'dt must be positive, got {p["dt"]!r}')
        self.law = str(p['law'])
        if self.law not in ('pairwise', 'shared'):
            raise ParameterError(f'law must be pairwise or shared (the estimator\'s), got '
                                 f'{self.law!r}')
        self.radius = float(p['interaction_radius'])
        self.profile_size = int(p['profile_size'])
        if self.law == 'shared' and not (self.radius > 0 and self.profile_size >= 1):
            raise ParameterError('the shared law needs interaction_radius > 0 and '
                                 'profile_size >= 1 (the estimator\'s values)')
        self._assignment(self.agents)   # validate now, not at the first message

    def _assignment(self, agents: list[str]) -> list[str]:
        n = len(self.robots)
        given = self.assignment_given
        if not given:
            return [agents[k % len(agents)] for k in range(n)]
        if len(given) != n:
            raise ParameterError(f'assignment + other_assignment name {len(given)} animals for '
                                 f'{n} robots (robots + other_robots); give one per robot, '
                                 f'or none to cycle through the model\'s agents')
        unknown = sorted(set(given) - set(agents))
        if unknown:
            raise ParameterError(f'assignment names animal(s) {", ".join(unknown)} not in the '
                                 f'model (agents: {", ".join(agents)})')
        return given

    def set_model(self, model):
        # one noise generator for the node's life: a live model is replaced every snapshot,
        # and re-seeding each time would repeat the same draw (a constant push, not noise)
        if not hasattr(self, 'rng'):
            self.rng = np.random.default_rng(self.seed)
        self.follower = follower_for(model, self._assignment(list(model.agents)), self.robots,
                                     noise=self.noise, seed=self.rng)
        self.updates += 1
        self.status = f'model of {model.n_agents} animals, dt {model.dt:g} s ({self.source})'
        if self.updates == 1 or self.refused_since_adopted:
            a = np.asarray(model.damping, dtype=float)
            self.node.get_logger().info(
                f'adopted {"a" if self.updates == 1 else "again a"} {self.status}: damping '
                f'{a.min():.3f}-{a.max():.3f}'
                + (f' (after {self.refused_since_adopted} refused updates)'
                   if self.refused_since_adopted else ''))
        self.refused_since_adopted = 0

    def on_params(self, msg: Float64MultiArray):
        dims = msg.layout.dim
        try:
            if len(dims) != 2:
                raise HerdInputError('/herd/model/params: expected 2 dims (agent x param)')
            rows, cols = dims[0].size, dims[1].size
            data = np.asarray(msg.data, dtype=float)[msg.layout.data_offset:]
            if data.size < rows * cols:
                raise HerdInputError(f'/herd/model/params: {data.size} numbers for '
                                     f'{rows} x {cols}')
            theta = data[:rows * cols].reshape(rows, cols)
            self.received += 1
            if self.received <= self.min_updates:
                self.status = (f'warming up: model update {self.received} of '
                               f'{self.min_updates} ignored')
                return
            problem, warning = damping_check(theta[:, 0], self.agents)
            if warning:
                self.node.get_logger().warning(warning, throttle_duration_sec=60.0)
            if problem:
                kept = 'keeping the previous model' if self.follower is not None else \
                    'robots hold still until a model is accepted'
                raise HerdInputError(f'/herd/model/params refused: {problem}; {kept}')
            if self.law == 'shared':
                model = shared_model_from_parameter_matrix(
                    theta, self.agents, self.dt, self.grid, self.radius, self.profile_size,
                    self.noise_cov)
            else:
                model = model_from_parameter_matrix(theta, self.agents, self.dt, self.grid,
                                                    self.noise_cov)
            self.set_model(model)
        except (HerdInputError, ParameterError) as exc:
            self.status = f'ignored parameters: {exc}'
            self.refused_since_adopted += 1
            self.node.get_logger().warn(str(exc), throttle_duration_sec=10.0)

    def on_noise(self, msg: Float64MultiArray):
        """Q_i of every agent from ``/herd/model/noise`` (agent × [qxx, qxy, qyx, qyy])."""
        data = np.asarray(msg.data, dtype=float)
        n = len(self.agents)
        if data.size != 4 * n or not np.isfinite(data).all():
            self.node.get_logger().warn(f'/herd/model/noise: expected {4 * n} finite numbers, '
                                        f'got {data.size}', throttle_duration_sec=10.0)
            return
        self.noise_cov = data.reshape(n, 2, 2)

    # -- the policy -----------------------------------------------------------------------
    def command(self, state: FleetObservation) -> np.ndarray:
        """The law's command: held on the herd clock and stepped at its ticks when the
        controller ticks faster than the model (:class:`HerdClockHold`), else advanced by
        the elapsed fraction of model steps (:meth:`HerdFollower.advance`)."""
        if self.follower is None:
            return np.zeros_like(state.positions)
        dt = self.follower.dt
        if state.period < dt:
            if getattr(self, 'hold', None) is None or self.hold.dt != dt:
                self.hold = HerdClockHold(dt)
            return self.hold.command(self.follower, state.last_command, state.positions,
                                     state.time, state.active)
        self.hold = None
        return self.follower.advance(state.last_command, state.positions, state.period,
                                     state.active)


#: Mode name -> policy class (``from_node(node)``, ``command(state)``).
POLICIES = {'herd_model': HerdModelPolicy, 'flocking': FlockingPolicy,
            'imitation': ImitationPolicyMode}


def yaw_from_quaternion(q) -> float:
    """Yaw (rad, CCW from east) of a geometry_msgs/Quaternion (ZYX convention)."""
    return float(np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z)))


class Controller(Node):
    def __init__(self):
        super().__init__('controller', automatically_declare_parameters_from_overrides=True)
        p = declare_parameters(self, DEFAULTS)
        self._configure(p)
        n = len(self.all_robots)
        self.positions = np.full((n, 2), np.nan)
        self.yaw = np.full(n, np.nan)
        self.velocity = np.zeros((n, 2))
        self.odom_time = np.full(n, np.nan)
        self.last_command = np.zeros((n, 2))
        self.counts = {key: np.zeros(n, dtype=np.int64)
                       for key in ('speed_limited', 'obstacle_limited', 'fence_limited',
                                   'stale_ticks')}
        for k, robot in enumerate(self.all_robots):
            self.create_subscription(Odometry, f'/fleet/{robot}/odom',
                                     lambda msg, k=k: self.on_odom(k, msg), 10)
        self.cmd_pubs = [self.create_publisher(Twist, f'/fleet/{r}/cmd_vel', 10)
                         for r in self.robots]
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.policy = POLICIES[self.mode].from_node(self)
        self._last_diag = -np.inf
        self.timer = self.create_timer(self.period, self.tick)
        describe_remaining_parameters(self, {
            'model.': 'the model (model file of herd-ros fit or the estimator, or an '
                      'imitation policy file; keys in the README)',
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
        self.mode = str(p['mode'])
        if self.mode not in POLICIES:
            raise ParameterError(f'mode {self.mode!r} is not available; modes: '
                                 f'{", ".join(POLICIES)}')
        if p['kinematics'] not in kin.KINEMATICS:
            raise ParameterError(f'kinematics must be holonomic or unicycle, got '
                                 f'{p["kinematics"]!r}')
        self.kinematics = p['kinematics']
        for name in ('rate_hz', 'max_speed', 'heading_gain', 'max_yaw_rate', 'odom_timeout_s',
                     'diagnostics_period_s', 'safety_horizon_s'):
            value = float(p[name])
            if not (np.isfinite(value) and value > 0):
                raise ParameterError(f'{name} must be a positive number, got {p[name]!r}')
            setattr(self, name, value)
        self.fence_margin = float(p['fence_margin'])
        if not self.fence_margin >= 0:
            raise ParameterError(f'fence_margin must be ≥ 0, got {p["fence_margin"]!r}')
        self.period = 1.0 / self.rate_hz
        self.horizon = max(self.safety_horizon_s, self.period)
        self.owned = np.array([r in self.robots for r in self.all_robots])

    # -- live parameters (rate_hz, max_speed, fence_margin, odom_timeout_s) ---------------
    def _validate_live(self, name, value):
        return number_problem(value, strict=name != 'fence_margin')

    def _apply_live(self, name, value):
        setattr(self, name, float(value))
        if name == 'rate_hz':
            self.period = 1.0 / self.rate_hz
            self.horizon = max(self.safety_horizon_s, self.period)
            self.timer.cancel()
            self.destroy_timer(self.timer)
            self.timer = self.create_timer(self.period, self.tick)

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_odom(self, k: int, msg: Odometry):
        pose, twist = msg.pose.pose, msg.twist.twist
        self.positions[k] = (pose.position.x, pose.position.y)
        self.yaw[k] = yaw_from_quaternion(pose.orientation)
        self.velocity[k] = kin.body_to_world(np.array([twist.linear.x, twist.linear.y]),
                                             self.yaw[k])
        self.odom_time[k] = self.now_s()

    def tick(self):
        now = self.now_s()
        active = ~stale_mask(self.odom_time, now, self.odom_timeout_s)
        last = np.where(self.owned[:, None], self.last_command, self.velocity)
        state = FleetObservation(list(self.all_robots), self.owned, self.positions.copy(),
                                 self.yaw.copy(), self.velocity.copy(), active, last,
                                 self.period, now)
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
        statuses = []
        for k, robot in enumerate(self.all_robots):
            if not self.owned[k]:
                continue
            level = OK if active[k] else WARN
            statuses.append(diagnostic_status(
                f'controller: {robot}', level,
                'ok' if active[k] else 'odometry stale: commanding zero',
                {'speed': float(np.hypot(*world[k])),
                 **{key: int(c[k]) for key, c in self.counts.items()}}, hardware_id=robot))
        statuses.append(diagnostic_status(
            'controller', OK if getattr(self.policy, 'follower', True) is not None else WARN,
            f'mode {self.mode}: {getattr(self.policy, "status", "")}',
            {'robots': len(self.robots), 'watched_robots': len(self.other_robots),
             'model_updates': getattr(self.policy, 'updates', 0)}))
        self.diag_pub.publish(diagnostic_array(self, statuses))


def main(args=None):
    exit_process(run_node(Controller, args=args))


if __name__ == '__main__':
    main()
