"""Velocity commands for velocity-driven robots from the double-integrator flocking law.

The Olfati-Saber / La–Sheng law (:func:`herd_ros.flocking.olfati_saber.flocking_acceleration`)
is written for double integrators, ``q̇ = p``, ``ṗ = u(q, p)``. Robots of the fleet take a
*velocity* (a Twist), so the controller keeps the law's velocity state ``p`` itself — the
commanded velocity — and integrates the acceleration into it once per control period ``T``
(the controller's ``1/rate_hz``), in ``n = ⌈T / h_max⌉`` substeps of ``h = T / n``
(semi-implicit Euler, as the offline simulator :mod:`herd_ros.flocking.scenarios`)::

    q⁰ = measured positions,  p⁰ = last commanded velocities (measured for robots not commanded)
    for s = 0 … n−1:
        u^s    = u(q^s, p^s; q_r + s h p_r, p_r; obstacles at s h)
        p^{s+1} = σ_vmax(p^s + h u^s)            # speed limit inside the loop: no wind-up
        q^{s+1} = q^s + h p^{s+1}
    command   = p^n

Positions are re-measured every period, so the loop is closed through the odometry; the
velocity state is the command itself (the robot's low-level controller tracks it), which is
what the double integrator assumes. The substeps keep the stiff terms stable: explicit Euler
needs ``h·c2`` (times the neighbour count for α, with ``c2β = 2√300 ≈ 35`` for β) well below
2, so a 10 Hz controller cannot take the law in one step; ``h_max = 0.01 s`` is the offline
simulator's step (0.02 s with 2 substeps). Clamping ``p`` to v_max inside the loop makes the
saturation the robots will apply part of the integrated state (anti-wind-up): the law never
believes it is moving faster than it can.
"""
from __future__ import annotations

import math

import numpy as np

from herd_ros.control.kinematics import limit_norm
from herd_ros.errors import HerdInputError
from herd_ros.flocking.olfati_saber import (CircularObstacles, FlockingParams,
                                            flocking_acceleration)


def flocking_velocity_command(positions: np.ndarray, velocities: np.ndarray,
                              target_position, target_velocity, period: float,
                              params: FlockingParams, obstacles: CircularObstacles | None = None,
                              max_step: float = 0.01, max_speed: float = math.inf) -> np.ndarray:
    """Velocity commands (N, 2) m/s for the next period from the flocking law (module docstring).

    Args:
        positions: (N, 2) m, measured positions q of every agent (neighbours included).
        velocities: (N, 2) m/s, the law's velocity state p (last commands; measured for agents
            this controller does not command).
        target_position: (2,) m, q_r at the start of the period. target_velocity: (2,) m/s, p_r
            (the target is advanced by p_r over the substeps).
        period: T (s), the control period the command will be held for.
        params: gains and constants. obstacles: circles at the start of the period (or None).
        max_step: h_max (s), the largest integration substep.
        max_speed: v_max (m/s) applied to p inside the loop.
    Returns:
        (N, 2) commanded world velocities p^n, ‖·‖ ≤ max_speed.
    """
    q = np.array(positions, dtype=float).reshape(-1, 2)
    p = np.array(velocities, dtype=float).reshape(-1, 2)
    if p.shape != q.shape or not (np.isfinite(q).all() and np.isfinite(p).all()):
        raise HerdInputError('flocking command: positions and velocities must be finite (N, 2) '
                             'arrays of the same shape')
    if not (period > 0 and max_step > 0):
        raise HerdInputError(f'flocking command: period ({period}) and max_step ({max_step}) '
                             f'must be > 0')
    n_sub = max(1, math.ceil(period / max_step - 1e-9))
    h = period / n_sub
    q_r = np.asarray(target_position, dtype=float).reshape(2)
    p_r = np.asarray(target_velocity, dtype=float).reshape(2)
    moving = obstacles is not None and len(obstacles) and np.any(obstacles.velocities != 0)
    for s in range(n_sub):  # a loop over substeps; agents are vectorised
        obs = obstacles.at_time(s * h) if moving else obstacles
        u = flocking_acceleration(q, p, q_r + s * h * p_r, p_r, params, obs)
        p = limit_norm(p + h * u, max_speed)
        q = q + h * p
    return p


class TargetEstimate:
    """Target position and velocity from timestamped fixes (finite differences of the stamps).

    ``update(t, xy)`` with the message stamp t (s) and position (2,) m; the velocity is
    ``(x_k − x_{k−1}) / (t_k − t_{k−1})`` over the last two fixes with distinct stamps
    (a repeated or older stamp is ignored). ``velocity_at(now)`` is zero once the last fix is
    older than ``timeout`` (s): a target that went silent is held still, not extrapolated.
    """

    def __init__(self, timeout: float = math.inf):
        self.timeout = float(timeout)
        self.stamp = math.nan
        self.position: np.ndarray | None = None
        self.velocity = np.zeros(2)
        self.received_at = math.nan
        self.updates = 0

    def update(self, stamp: float, position, received_at: float) -> bool:
        """Take a fix; returns False (and ignores it) if non-finite or not newer."""
        xy = np.asarray(position, dtype=float).reshape(2)
        if not (np.isfinite(xy).all() and math.isfinite(stamp)):
            return False
        if self.position is not None:
            dt = stamp - self.stamp
            if not dt > 0:
                return False
            self.velocity = (xy - self.position) / dt
        self.stamp, self.position, self.received_at = stamp, xy, received_at
        self.updates += 1
        return True

    def velocity_at(self, now: float) -> np.ndarray:
        """p_r (2,) m/s, zero if the last fix arrived more than ``timeout`` before ``now``."""
        if not now - self.received_at <= self.timeout:
            return np.zeros(2)
        return self.velocity


def centroid_of_valid(points: np.ndarray) -> np.ndarray:
    """Mean (2,) of the rows of (M, 2) that are finite (NaN poses ignored); NaN if none."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    ok = np.isfinite(pts).all(axis=1)
    return pts[ok].mean(axis=0) if ok.any() else np.full(2, np.nan)
