"""Boids-style swarm of single-integrator agents (Rahman, White et al., ACC 2023, eq. 1-2).

Per agent i and step τ (Δt constant)::

    v_i^τ   = σ_vmax( Σ_k k_k θ_k,i(p^τ, v^{τ−1}) )          commanded velocity (m/s)
    p_i^τ+1 = p_i^τ + Δt v_i^τ                                single integrator (m)
    σ_vmax(u) = u if ‖u‖ ≤ v_max else v_max u/‖u‖            speed saturation

θ_k,i are the policy features of :mod:`herd_ros.imitation.policies` (they read the previous
velocities v^{τ−1} for alignment, inertia and the heading). Optional measurement noise is
added to the *recorded* positions only, ``q = p + N(0, noise_std² I)``; the swarm itself moves
noise-free. :func:`commanded_velocities` is the pure law a controller needs: positions and
previous velocities of all agents (+ walls, policy) -> commanded velocities.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.imitation.policies import check_policies, check_walls, policy_features
from herd_ros.trajectory import HerdTrajectory


@dataclass
class ImitationPolicy:
    """A swarm policy: v_i = σ_vmax(Σ_k gains[k] θ_k,i) with neighbours within ``radius``.

    Attributes:
        policies: K policy names. gains: (K,) k_k. gains_se: (K,) standard errors (or None).
        radius: communication radius r (m). v_max: speed limit (m/s). dt: step (s).
        walls: enclosure (xmin, xmax, ymin, ymax) in m, or None.
    """

    policies: list[str]
    gains: np.ndarray
    radius: float
    v_max: float
    dt: float
    gains_se: np.ndarray | None = None
    walls: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.policies = check_policies(self.policies)
        self.gains = np.asarray(self.gains, dtype=float).reshape(-1)
        if self.gains.shape != (len(self.policies),) or not np.isfinite(self.gains).all():
            raise HerdInputError(f'gains: need {len(self.policies)} finite numbers, one per '
                                 f'policy (got {self.gains.tolist()})')
        if self.gains_se is not None:
            self.gains_se = np.asarray(self.gains_se, dtype=float).reshape(-1)
        for name in ('radius', 'v_max', 'dt'):
            value = float(getattr(self, name))
            if not np.isfinite(value) or value <= 0:
                raise HerdInputError(f'{name}: must be a positive number (got {value})')
            setattr(self, name, value)
        self.walls = check_walls(self.walls)


def saturate(u: np.ndarray, v_max: float) -> np.ndarray:
    """σ_vmax(u): scale the 2-vectors (..., 2) that are faster than v_max down to v_max."""
    speed = np.linalg.norm(u, axis=-1, keepdims=True)
    return u * np.minimum(1.0, v_max / np.maximum(speed, 1e-300))


def commanded_velocities(positions: np.ndarray, previous_velocities: np.ndarray,
                         policy: ImitationPolicy, walls=None) -> np.ndarray:
    """v = σ_vmax(Σ_k k_k θ_k(p, v_prev)) for every agent of one or many frames.

    Args:
        positions: (..., N, 2) m. previous_velocities: (..., N, 2) m/s.
        policy: the learned or hand-written policy.
        walls: overrides ``policy.walls`` when given (xmin, xmax, ymin, ymax).

    Returns:
        (..., N, 2) commanded velocities, m/s, speed ≤ v_max.
    """
    walls = policy.walls if walls is None else walls
    theta = policy_features(positions, previous_velocities, policy.policies, policy.radius,
                            walls)
    return saturate(np.einsum('...kd,k->...d', theta, policy.gains), policy.v_max)


def simulate(policy: ImitationPolicy, initial_positions: np.ndarray,
             initial_velocities: np.ndarray | None, n_steps: int, *,
             noise_std: float = 0.0, rng=None) -> tuple[np.ndarray, np.ndarray]:
    """Roll the swarm forward (all runs at once).

    Args:
        initial_positions: (R, N, 2) m at step 0. initial_velocities: (R, N, 2) m/s, the
            "previous" velocities seen at step 0 (zeros if None).
        n_steps: number of time stamps to return (T ≥ 1).
        noise_std: std (m) of the Gaussian noise added to the returned positions.

    Returns:
        positions (R, T, N, 2) as recorded (with noise) and the true velocities (R, T, N, 2)
        commanded at each step (the last one is the velocity leaving the last position).
    """
    rng = np.random.default_rng(rng)
    p = np.array(initial_positions, dtype=float)
    v = np.zeros_like(p) if initial_velocities is None else np.array(initial_velocities, float)
    R, N = p.shape[:2]
    pos = np.empty((R, n_steps, N, 2))
    vel = np.empty((R, n_steps, N, 2))
    for t in range(n_steps):  # a loop over time; agents and runs are vectorised
        v = commanded_velocities(p, v, policy)
        pos[:, t], vel[:, t] = p, v
        p = p + policy.dt * v
    if noise_std > 0:
        pos = pos + rng.normal(0.0, noise_std, pos.shape)
    return pos, vel


def random_starts(n_runs: int, n_agents: int, region, *, initial_speed: float = 0.0,
                  rng=None) -> tuple[np.ndarray, np.ndarray]:
    """Uniform random positions in ``region`` (xmin, xmax, ymin, ymax) and previous
    velocities of random direction and speed uniform in [0, initial_speed]: (R, N, 2) each."""
    rng = np.random.default_rng(rng)
    x0, x1, y0, y1 = [float(a) for a in region]
    p = np.stack([rng.uniform(x0, x1, (n_runs, n_agents)),
                  rng.uniform(y0, y1, (n_runs, n_agents))], axis=-1)
    ang = rng.uniform(0, 2 * np.pi, (n_runs, n_agents))
    speed = rng.uniform(0, initial_speed, (n_runs, n_agents))
    v = np.stack([speed * np.cos(ang), speed * np.sin(ang)], axis=-1)
    return p, v


def simulate_runs(policy: ImitationPolicy, *, n_agents: int, n_runs: int, duration: float,
                  region=(0.0, 10.0, 0.0, 10.0), noise_std: float = 0.0,
                  initial_speed: float | None = None, rng=None) -> list[HerdTrajectory]:
    """Many runs from random starts in ``region``; each a :class:`HerdTrajectory` labelled
    ``run`` = '0', '1', ... with ``meta['velocities']`` the true commanded velocities.

    ``duration`` (s) gives T = round(duration/dt) + 1 time stamps. ``initial_speed`` defaults
    to v_max (speeds uniform in [0, v_max]).
    """
    rng = np.random.default_rng(rng)
    n_steps = int(round(duration / policy.dt)) + 1
    p0, v0 = random_starts(n_runs, n_agents, region,
                           initial_speed=policy.v_max if initial_speed is None
                           else initial_speed, rng=rng)
    pos, vel = simulate(policy, p0, v0, n_steps, noise_std=noise_std, rng=rng)
    times = np.arange(n_steps) * policy.dt
    agents = [f'a{i}' for i in range(n_agents)]
    return [HerdTrajectory(times.copy(), list(agents), pos[r], str(r),
                           {'velocities': vel[r], 'initial_velocities': v0[r]})
            for r in range(n_runs)]
