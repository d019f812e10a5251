"""Mode ``herd_model`` of the controller: each robot follows its assigned animal's learned
law (:mod:`herd_ros.control.herd_follower`), the model from a model file's ``model.*``
parameters or live from the estimator's ``/herd/model/params``. The shell of the mode:
parameters, subscriptions and the checks of each model adopted
(:mod:`herd_ros.control.damping`)."""
from __future__ import annotations

import numpy as np
from std_msgs.msg import Float64MultiArray

from herd_ros.control.damping import damping_check
from herd_ros.control.fleet_observation import FleetObservation
from herd_ros.control.herd_follower import (HerdClockHold, HerdFollower, follower_for,
                                            model_from_parameter_matrix,
                                            shared_model_from_parameter_matrix)
from herd_ros.errors import HerdInputError
from herd_ros.model.any_model import any_model_from_dict
from herd_ros.model.model_file import check_agent_id
from herd_ros.model.rbf_field import FieldGrid
from herd_ros.nodes.ros_common import ParameterError, declare_parameters
from herd_ros.params.controller import HERD_MODEL as HERD_MODEL_DEFAULTS


class HerdModelPolicy:
    """Mode ``herd_model``: each robot follows its assigned animal's learned law.

    Model from the ``model.*`` parameters (``--params-file model.yaml``) or, with
    ``model_source: topic``, live from ``/herd/model/params`` (see
    :func:`~herd_ros.control.herd_follower.model_from_parameter_matrix`).
    """

    def __init__(self, node, p: dict):
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
    def from_node(cls, node) :
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
