"""Controller mode ``imitation``: every robot runs a learned swarm policy (issue 7).

The policy is the ``model.*`` block of a policy file (``model.kind: imitation``, written by
``herd-ros imitate``), given with ``--params-file``. Each robot's neighbours are the other
robots (own and ``other_robots``) with fresh odometry. The law is the discrete one it was
learned as (:func:`herd_ros.imitation.boids.commanded_velocities`)::

    v_i^τ = σ_vmax(Σ_k k_k θ_k,i(p^τ, v^{τ−1})),   one step every model.dt

with p^τ the measured positions and v^{τ−1} the velocities commanded on the previous step
(after the safety layer; measured for robots this controller does not command). The law is
stepped once every ``model.dt`` of the node clock and held between steps, so ``rate_hz`` may
be any multiple of 1/model.dt (equal to it is the natural choice). Walls of the wall policies
are ``model.walls`` or, if absent, the bounding box of the controller's ``fence``.
"""
from __future__ import annotations

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.imitation.boids import commanded_velocities
from herd_ros.imitation.policy_file import policy_from_dict
from herd_ros.nodes.ros_common import ParameterError


class ImitationPolicyMode:
    """Mode ``imitation`` (see the module docstring); ``command(state)`` -> (R, 2) m/s."""

    def __init__(self, node):
        self.node = node
        flat = {k: v.value for k, v in node.get_parameters_by_prefix('model').items()}
        if flat.get('kind') != 'imitation':
            raise ParameterError('mode imitation needs a policy file (model.kind: imitation): '
                                 'pass it with --ros-args --params-file policy.yaml')
        try:
            self.policy = policy_from_dict({'controller': {'ros__parameters': {'model': flat}}},
                                           'parameters model.*')
        except HerdInputError as exc:
            raise ParameterError(str(exc)) from None
        self.walls = self.policy.walls
        if self.walls is None and node.fence is not None:
            v = node.fence.vertices
            self.walls = np.array([v[:, 0].min(), v[:, 0].max(), v[:, 1].min(), v[:, 1].max()])
        self.dt = self.policy.dt
        self.held = None
        self.next_step = -np.inf
        self.updates = 0
        ratio = node.period / self.dt
        note = ''
        if ratio > 1.0 + 1e-6:
            note = f'; rate_hz is slower than 1/model.dt ({1 / self.dt:g} Hz): the law steps ' \
                   f'every {node.period:g} s instead of {self.dt:g} s'
        elif abs(1.0 / ratio - round(1.0 / ratio)) > 1e-6:
            note = '; rate_hz is not a multiple of 1/model.dt: steps are rounded to ticks'
        if node.max_speed < self.policy.v_max:
            note += f'; max_speed {node.max_speed:g} < model.v_max {self.policy.v_max:g}'
        if note:
            node.get_logger().warn(note[2:])
        self.status = (f'imitation policy {", ".join(self.policy.policies)} (r '
                       f'{self.policy.radius:g} m, v_max {self.policy.v_max:g} m/s, dt '
                       f'{self.dt:g} s){note}')

    @classmethod
    def from_node(cls, node) -> 'ImitationPolicyMode':
        """The policy, read from the node's parameters."""
        return cls(node)

    def command(self, state) -> np.ndarray:
        """World velocities (R, 2) of the learned swarm policy, stepped at the model's dt."""
        present = state.active & np.isfinite(state.positions).all(axis=1) \
            & np.isfinite(state.last_command).all(axis=1)
        # a step is due when a full model.dt has passed (half a tick of slack for jitter)
        if self.held is None or state.time >= self.next_step - 0.5 * state.period:
            out = np.full_like(state.positions, np.nan)
            if present.any():
                out[present] = commanded_velocities(state.positions[present],
                                                    state.last_command[present], self.policy,
                                                    walls=self.walls)
            self.held = out
            step = max(self.dt, state.period)
            self.next_step = self.next_step + step            # anchored: no drift with jitter
            if not self.next_step > state.time:
                self.next_step = state.time + step
            self.updates += 1
            return out.copy()
        held = self.held.copy()
        held[~present] = np.nan
        return held
