"""Forward simulation of a learned (or true) herd model, eq. 2 with noise w_i ~ N(0, Q_i)
(or the model's stop-and-go noise regimes, :mod:`herd_ros.model.noise_regimes`).

    u^{τ+1} = a ⊙ u^τ + Σ_j f_ij(p^τ) + g_i(p^τ) + w^τ,     p^{τ+1} = p^τ + Δt u^τ

All agents advance together (arrays of shape (N, 2)); one Python step per time step.
"""
from __future__ import annotations

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.model.herd_model import HerdModel
from herd_ros.model.noise_regimes import noise_for
from herd_ros.model.velocity_memory import remember
from herd_ros.trajectory import HerdTrajectory


def simulate(model: HerdModel, steps: int, initial_positions: np.ndarray,
             initial_velocities: np.ndarray | None = None, seed=None, noise: bool = True,
             noise_scale: float = 1.0, t0: float = 0.0, progress=None) -> HerdTrajectory:
    """Simulate ``steps`` positions (including the initial one) of every agent.

    Args:
        model: the herd model.
        initial_positions: (N, 2) p^0.
        initial_velocities: (N, 2) u^0 (default zero).
        seed: seed of the noise generator (``numpy.random.default_rng``).
        noise: draw w from Q_i, or from the model's noise regimes (else the deterministic
            law).
    Returns:
        a :class:`HerdTrajectory` with times t0 + Δt·τ.
    """
    if steps < 1:
        raise HerdInputError(f'steps must be ≥ 1, got {steps}')
    n = model.n_agents
    p = np.array(initial_positions, dtype=float).reshape(n, 2)
    u = (np.zeros((n, 2)) if initial_velocities is None
         else np.array(initial_velocities, dtype=float).reshape(n, 2))
    source = noise_for(model, seed, noise_scale) if noise else None
    out = np.empty((steps, n, 2))
    out[0] = p
    kappa = getattr(model, 'velocity_memory', 1.0)
    mean_u = u                              # ū^0 = u^0 (velocity memory; ū = u at κ = 1)
    for tau in range(1, steps):
        u_next = model.next_velocity(mean_u, p, compiled=True)
        if noise:
            u_next = u_next + source.draw()
        p = p + model.dt * u
        u = u_next
        mean_u = remember(kappa, mean_u, u)
        out[tau] = p
        if progress is not None and tau % 1000 == 0:
            progress(1000)
    times = t0 + model.dt * np.arange(steps)
    return HerdTrajectory(times, list(model.agents), out)


def first_pairs(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each agent of ``positions`` (T, N, 2), the first step k where it is present at k
    and k + 1 (N,), and whether it has such a step at all (N,)."""
    p = np.asarray(positions, dtype=float)
    both = np.isfinite(p[:-1]).all(-1) & np.isfinite(p[1:]).all(-1)     # (T−1, N)
    return np.argmax(both, axis=0), both.any(axis=0)


def simulate_from(model: HerdModel, run: HerdTrajectory, steps: int | None = None, seed=None,
                  noise: bool = True) -> HerdTrajectory:
    """Simulate from the start of ``run``: from its first two consecutive steps where every
    agent is present (p^0, u^0 = (p^1 − p^0)/Δt), for the rest of the run by default. A run
    with no such pair (collars that never overlap) starts each agent from its own first two
    consecutive positions."""
    p = np.asarray(run.positions, dtype=float)
    complete = (np.isfinite(p[:-1]) & np.isfinite(p[1:])).all(-1).all(-1)
    if complete.any():
        k0 = int(np.argmax(complete))
        p0, p1 = p[k0], p[k0 + 1]
    else:
        k0 = 0
        first, _ = first_pairs(p)
        idx = np.arange(p.shape[1])
        p0, p1 = p[first, idx], p[first + 1, idx]
    steps = run.n_steps - k0 if steps is None else steps
    return simulate(model, steps, p0, (p1 - p0) / model.dt, seed=seed, noise=noise,
                    t0=float(run.times[k0]))
