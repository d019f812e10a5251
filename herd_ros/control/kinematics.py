"""Robot kinematics for a fleet: holonomic and unicycle models, limits, frames (REP-103).

Frames: the world frame is ``map`` (x east, y north); a robot's body frame has x forward,
y left, and its yaw ψ is measured counter-clockwise from east. A body velocity
b = (v_x, v_y) and the world velocity w are related by the rotation R(ψ)::

    w = R(ψ) b,   b = R(ψ)ᵀ w,   R(ψ) = [[cos ψ, −sin ψ], [sin ψ, cos ψ]]

State of N robots (:class:`FleetState`): positions (N, 2) m, yaw (N,) rad, world velocity
(N, 2) m/s. Both models integrate with a step h (s) and respect

* a speed limit ‖w‖ ≤ v_max (m/s),
* an acceleration limit ‖w⁺ − w‖ ≤ a_max h (m/s², on the velocity vector for the holonomic
  model, on the signed forward speed for the unicycle),
* a yaw-rate limit |ω| ≤ ω_max (rad/s).

Holonomic (omnidirectional) robot, commanded (v_x, v_y, ω) in the body frame::

    w⁺ = clip_a(R(ψ) b),  p⁺ = p + h w⁺,  ψ⁺ = ψ + h ω

Unicycle (differential drive), commanded forward speed v and yaw rate ω; the exact arc
(e.g. Siegwart & Nourbakhsh, *Autonomous Mobile Robots*, 2004, §3.2) is approximated by the
midpoint heading, exact to O(h³)::

    v⁺ = clip_a(v),  ψ⁺ = ψ + h ω,  p⁺ = p + h v⁺ [cos ψ̄, sin ψ̄],  ψ̄ = ψ + h ω / 2

A unicycle tracks a desired world velocity w_d with the usual heading controller
(turn toward the desired course, drive at the projection of w_d on the heading, never
backwards)::

    e = wrap(atan2(w_d,y, w_d,x) − ψ),  ω = clip(k_ψ e, ±ω_max),  v = ‖w_d‖ max(cos e, 0)

Everything is vectorised over robots; nothing here imports rclpy.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from herd_ros.errors import HerdInputError

KINEMATICS = ('holonomic', 'unicycle')


def check_kinematics(name: str) -> str:
    """``name`` if it is one of :data:`KINEMATICS`; one clear error otherwise."""
    if name not in KINEMATICS:
        raise HerdInputError(f'kinematics must be one of {", ".join(KINEMATICS)}, got {name!r}')
    return name


def wrap_angle(angle):
    """Angles (rad) wrapped to [−π, π)."""
    return (np.asarray(angle, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def body_to_world(body_velocity: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """w = R(ψ) b: body (N, 2) [forward, left] m/s, yaw (N,) rad -> world (N, 2) [east, north]."""
    b = np.asarray(body_velocity, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * b[..., 0] - s * b[..., 1], s * b[..., 0] + c * b[..., 1]], axis=-1)


def world_to_body(world_velocity: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """b = R(ψ)ᵀ w: world (N, 2) and yaw (N,) -> body (N, 2) [forward, left]."""
    w = np.asarray(world_velocity, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * w[..., 0] + s * w[..., 1], -s * w[..., 0] + c * w[..., 1]], axis=-1)


def heading_vector(yaw: np.ndarray) -> np.ndarray:
    """Unit forward vectors (N, 2) of yaws (N,)."""
    return np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)


def limit_norm(vectors: np.ndarray, max_norm) -> np.ndarray:
    """Scale each row of ``vectors`` (..., 2) down to a Euclidean norm ≤ ``max_norm``.

    The direction is kept (a saturated velocity still points where the law wanted).
    ``max_norm`` may be a scalar or broadcast over rows; ``inf`` disables the limit.
    """
    v = np.asarray(vectors, dtype=float)
    norm = np.sqrt((v ** 2).sum(-1, keepdims=True))
    limit = np.asarray(max_norm, dtype=float)[..., None] if np.ndim(max_norm) else max_norm
    with np.errstate(divide='ignore', invalid='ignore'):
        scale = np.where(norm > limit, limit / norm, 1.0)
    return v * scale


def limit_acceleration(target: np.ndarray, current: np.ndarray, max_accel: float,
                       step: float) -> np.ndarray:
    """Move velocity vectors ``current`` (..., 2) toward ``target`` by at most a_max·h each."""
    current = np.asarray(current, dtype=float)
    return current + limit_norm(np.asarray(target, dtype=float) - current, max_accel * step)


@dataclass
class FleetState:
    """N robots: positions (N, 2) m in ``map``, yaw (N,) rad CCW from east, world velocity
    (N, 2)."""

    positions: np.ndarray
    yaw: np.ndarray
    velocity: np.ndarray

    @staticmethod
    def at_rest(poses: np.ndarray) -> 'FleetState':
        """Robots at rest at ``poses`` (N, 3) rows [x, y, yaw]."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        return FleetState(poses[:, :2].copy(), wrap_angle(poses[:, 2]), np.zeros((len(poses), 2)))

    @property
    def body_velocity(self) -> np.ndarray:
        """(N, 2) [forward, left] m/s."""
        return world_to_body(self.velocity, self.yaw)

    def copy(self) -> 'FleetState':
        """A copy of the state (arrays copied)."""
        return FleetState(self.positions.copy(), self.yaw.copy(), self.velocity.copy())


def step_holonomic(state: FleetState, body_command: np.ndarray, yaw_rate: np.ndarray,
                   step: float, max_speed: float, max_accel: float = np.inf,
                   max_yaw_rate: float = np.inf) -> FleetState:
    """One step h of omnidirectional robots; body_command (N, 2) [v_x, v_y], yaw_rate (N,)."""
    target = limit_norm(body_to_world(body_command, state.yaw), max_speed)
    velocity = limit_norm(limit_acceleration(target, state.velocity, max_accel, step), max_speed)
    omega = np.clip(np.asarray(yaw_rate, dtype=float), -max_yaw_rate, max_yaw_rate)
    return FleetState(state.positions + step * velocity, wrap_angle(state.yaw + step * omega),
                      velocity)


def step_unicycle(state: FleetState, forward_speed: np.ndarray, yaw_rate: np.ndarray,
                  step: float, max_speed: float, max_accel: float = np.inf,
                  max_yaw_rate: float = np.inf) -> FleetState:
    """One step h of unicycles; forward_speed (N,) m/s, yaw_rate (N,) rad/s (midpoint heading)."""
    heading = heading_vector(state.yaw)
    speed_now = (state.velocity * heading).sum(-1)  # signed speed along the heading
    target = np.clip(np.asarray(forward_speed, dtype=float), -max_speed, max_speed)
    speed = speed_now + np.clip(target - speed_now, -max_accel * step, max_accel * step)
    speed = np.clip(speed, -max_speed, max_speed)
    omega = np.clip(np.asarray(yaw_rate, dtype=float), -max_yaw_rate, max_yaw_rate)
    mid = state.yaw + 0.5 * step * omega
    new_yaw = wrap_angle(state.yaw + step * omega)
    positions = state.positions + step * speed[:, None] * heading_vector(mid)
    return FleetState(positions, new_yaw, speed[:, None] * heading_vector(new_yaw))


def unicycle_tracking(desired_velocity: np.ndarray, yaw: np.ndarray, heading_gain: float = 2.0,
                      max_yaw_rate: float = np.inf, min_speed: float = 1e-6):
    """Forward speed v (N,) and yaw rate ω (N,) of unicycles tracking world velocities (N, 2).

    e = wrap(atan2(w_y, w_x) − ψ), ω = clip(k_ψ e, ±ω_max), v = ‖w‖ max(cos e, 0): the robot
    turns toward the desired course and only drives the part of w_d along its heading, so
    its realised velocity v·[cos ψ, sin ψ] is the projection of w_d on the heading (never
    longer than w_d, never pointing away from it). Below ``min_speed`` it holds still.
    """
    w = np.asarray(desired_velocity, dtype=float)
    speed = np.sqrt((w ** 2).sum(-1))
    error = wrap_angle(np.arctan2(w[..., 1], w[..., 0]) - yaw)
    moving = speed > min_speed
    omega = np.where(moving, np.clip(heading_gain * error, -max_yaw_rate, max_yaw_rate), 0.0)
    forward = np.where(moving, speed * np.maximum(np.cos(error), 0.0), 0.0)
    return forward, omega


def twist_from_world_velocity(desired_velocity: np.ndarray, yaw: np.ndarray, kinematics: str,
                              heading_gain: float = 2.0, max_yaw_rate: float = np.inf):
    """Body-frame commands (v_x (N,), v_y (N,), ω (N,)) realising world velocities (N, 2).

    Holonomic: [v_x, v_y] = R(ψ)ᵀ w, ω = 0 (heading is free). Unicycle: :func:`unicycle_tracking`
    with v_y = 0.
    """
    check_kinematics(kinematics)
    if kinematics == 'holonomic':
        body = world_to_body(desired_velocity, yaw)
        return body[..., 0], body[..., 1], np.zeros_like(body[..., 0])
    forward, omega = unicycle_tracking(desired_velocity, yaw, heading_gain, max_yaw_rate)
    return forward, np.zeros_like(forward), omega


def realised_world_velocity(forward: np.ndarray, lateral: np.ndarray, yaw: np.ndarray,
                            kinematics: str) -> np.ndarray:
    """World velocity (N, 2) a body command produces (a unicycle ignores v_y)."""
    check_kinematics(kinematics)
    lateral = np.zeros_like(np.asarray(forward, float)) if kinematics == 'unicycle' else lateral
    return body_to_world(np.stack([forward, lateral], axis=-1), yaw)
