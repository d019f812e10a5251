"""Controller mode ``flocking``: the fleet flocks around a moving target (issue 6).

The target is the centroid of ``/herd/poses`` (``target_source: herd_centroid``; NaN poses
are ignored) or a geometry_msgs/PointStamped topic (``target_source: point``), both in the
``map`` frame. Its velocity is the finite difference of the last two fixes over their header
stamps (:class:`~herd_ros.control.flocking_command.TargetEstimate`). Gains and obstacles come
from ``flocking.*`` (``config/flocking.yaml``); the controller's safety ``obstacles`` are
added to the law's β-obstacles too, so the flock steers around what the safety layer would
otherwise only block. Each tick the double-integrator law is integrated into a velocity
command by :func:`~herd_ros.control.flocking_command.flocking_velocity_command`.
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PointStamped, PoseArray

from herd_ros.control.flocking_command import (TargetEstimate, centroid_of_valid,
                                               flocking_velocity_command)
from herd_ros.errors import HerdInputError
from herd_ros.flocking.olfati_saber import CircularObstacles, FlockingParams
from herd_ros.nodes.ros_common import declare_parameters
from herd_ros.nodes.ros_common import ParameterError, pose_array_xy, stamp_to_seconds
from herd_ros.params.controller import FLOCKING as FLOCKING_DEFAULTS

TARGET_SOURCES = {'herd_centroid': '/herd/poses', 'point': ''}


class FlockingPolicy:
    """Mode ``flocking`` (see the module docstring); ``command(state)`` -> (R, 2) m/s."""

    def __init__(self, node, p: dict):
        self.node = node
        self.source = str(p['target_source'])
        if self.source not in TARGET_SOURCES:
            raise ParameterError(f'target_source must be herd_centroid or point, got '
                                 f'{self.source!r}')
        self.topic = str(p['target_topic']) or TARGET_SOURCES[self.source]
        if not self.topic:
            raise ParameterError('target_source point needs target_topic (a '
                                 'geometry_msgs/PointStamped topic in the map frame)')
        self.max_step = float(p['integration_step_s'])
        timeout = float(p['target_timeout_s'])
        if not (self.max_step > 0 and timeout > 0):
            raise ParameterError('integration_step_s and target_timeout_s must be positive')
        flat = {k: v.value for k, v in node.get_parameters_by_prefix('flocking').items()}
        try:
            self.params = FlockingParams.from_mapping(flat, where='parameters flocking')
            law_obstacles = CircularObstacles.from_flat(flat.get('obstacles', []))
        except HerdInputError as exc:
            raise ParameterError(str(exc)) from None
        safety = node.obstacles.circles
        self.obstacles = CircularObstacles(
            np.vstack([law_obstacles.centres, safety[:, :2]]),
            np.concatenate([law_obstacles.radii, safety[:, 2]]))
        self.target = TargetEstimate(timeout)
        self.updates = 0
        if self.source == 'point':
            node.create_subscription(PointStamped, self.topic, self.on_point, 10)
        else:
            node.create_subscription(PoseArray, self.topic, self.on_poses, 10)
        self.status = f'waiting for a target on {self.topic}'

    @classmethod
    def from_node(cls, node) -> 'FlockingPolicy':
        """The policy with its parameters declared on ``node``."""
        return cls(node, declare_parameters(node, FLOCKING_DEFAULTS))

    # -- target ---------------------------------------------------------------------------
    def _take(self, stamp: float, xy):
        if self.target.update(stamp, xy, self.node.now_s()):
            self.updates = self.target.updates
            self.status = (f'tracking {self.source} {self.topic} '
                           f'(γ {self.params.gamma_mode}, {len(self.obstacles)} obstacles)')

    def on_point(self, msg: PointStamped):
        """Take a target fix from a PointStamped."""
        self._take(stamp_to_seconds(msg.header.stamp), (msg.point.x, msg.point.y))

    def on_poses(self, msg: PoseArray):
        """Take the centroid of the valid poses of /herd/poses as the target."""
        self._take(stamp_to_seconds(msg.header.stamp), centroid_of_valid(pose_array_xy(msg)))

    # -- the policy -----------------------------------------------------------------------
    def command(self, state) -> np.ndarray:
        """World velocities (R, 2): the flocking law integrated over one period."""
        out = np.full_like(state.positions, np.nan)
        present = state.active & np.isfinite(state.positions).all(axis=1) \
            & np.isfinite(state.last_command).all(axis=1)
        if self.target.position is None:
            out[present] = 0.0                          # no target yet: hold still
            return out
        if present.any():
            out[present] = flocking_velocity_command(
                state.positions[present], state.last_command[present], self.target.position,
                self.target.velocity_at(state.time), state.period, self.params,
                self.obstacles, max_step=self.max_step, max_speed=self.node.max_speed)
        return out
