"""Velocity memory: the damping of eq. 2 acting on a smoothed velocity.

The paper's model (Schwager, Anderson & Rus 2007, eq. 2) damps the last velocity,
u_i^{τ+1} = a_i u_i^τ + Σ_j f_ij + g_i + w_i. Real animals keep a heading over more than
one step and jitter within it (a collar's or an RTLS tag's noise, a head turn), so a
generalisation with one herd-wide constant κ ∈ (0, 1] (the *velocity memory*) replaces u^τ
by its exponentially weighted mean

    ū_i^τ = (1 − κ) ū_i^{τ−1} + κ u_i^τ,        u_i^{τ+1} = a_i ū_i^τ + Σ_j f_ij + g_i + w_i.

κ = 1 is the paper's model exactly. For the damping-only model the one-step predictor
p̂^{τ+2} = p^{τ+1} + Δt a ū^τ is the steady-state Kalman predictor of a velocity that
follows an AR(1) and is observed with white noise — damped-trend exponential smoothing with
the level on the data (Gardner & McKenzie 1985, *Management Science* 31:1237; Gardner 1985,
*J. Forecasting* 4:1). The model stays linear in θ_i for a given κ, so every fit (least
squares, robust, RLS) is unchanged with ū in the damping column; κ itself is chosen by
blocked cross-validation (:mod:`herd_ros.estimation.model_selection`). The mean restarts
(ū = u) at an agent's first velocity after a gap, so nothing is carried across one.
"""
from __future__ import annotations

import numpy as np

from herd_ros.errors import HerdInputError

try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is an install requirement
    def njit(*args, **kwargs):
        """numba's decorator where numba is absent: the function unchanged."""
        return (lambda f: f) if not args or not callable(args[0]) else args[0]


def check_memory(memory) -> float:
    """κ as a float in (0, 1], or one clear error."""
    try:
        k = float(memory)
    except (TypeError, ValueError):
        raise HerdInputError(f'velocity memory must be a number in (0, 1], got {memory!r}') \
            from None
    if not 0.0 < k <= 1.0:
        raise HerdInputError(f'velocity memory must be in (0, 1], got {memory}')
    return k


def check_memories(memory, n_agents: int) -> np.ndarray:
    """κ per agent (N,) from one number or one per agent, each in (0, 1]; one clear error
    otherwise."""
    values = np.atleast_1d(np.asarray(memory, dtype=object)).ravel()
    if len(values) not in (1, n_agents):
        raise HerdInputError(f'velocity memory needs one number or one per agent ({n_agents}), '
                             f'got {len(values)}')
    k = np.array([check_memory(v) for v in values], dtype=float)
    return np.full(n_agents, k[0]) if len(k) == 1 else k


def memory_velocities(velocity: np.ndarray, memory) -> np.ndarray:
    """ū^τ = (1 − κ) ū^{τ−1} + κ u^τ: the velocity the damping acts on, (T, N, 2) -> (T, N, 2).

    κ = ``memory`` ∈ (0, 1], one for the herd or one per agent (N,). κ = 1 is the paper's
    model (ū = u, the same array back). With
    κ < 1 the damping term a_i ū_i of eq. 2 acts on an exponentially weighted mean of the
    agent's recent velocities (a first-order low-pass, time constant Δt(1 − κ)/κ): its
    heading persists over more than one step, and a step of jitter does not reverse it.
    For the damping-only model this is the steady-state Kalman predictor of a velocity
    that follows an AR(1) and is observed with white noise, i.e. Gardner & McKenzie's
    damped-trend exponential smoothing with the level on the data (Gardner 1985, J.
    Forecasting 4:1). The mean restarts (ū = u) at an agent's first velocity after a gap
    (NaN), so nothing is carried across a gap.
    """
    u = np.asarray(velocity, dtype=float)
    flat = u.reshape(u.shape[0], -1, u.shape[-1]) if u.ndim >= 2 else u
    k = check_memories(memory, flat.shape[1] if u.ndim >= 3 else 1)
    if (k == 1.0).all() or u.shape[0] == 0:
        return u
    if len(k) != flat.shape[1]:
        raise HerdInputError(f'{len(k)} velocity memories for {flat.shape[1]} agents')
    return _ewma_restart(np.ascontiguousarray(flat), k).reshape(u.shape)


@njit(cache=True)
def _ewma_restart(u, kappa):  # pragma: no cover - compiled
    T, N, D = u.shape
    out = np.empty_like(u)
    for i in range(N):
        k = kappa[i]
        fresh = True
        for t in range(T):
            gap = False
            for d in range(D):
                if not np.isfinite(u[t, i, d]):
                    gap = True
            if gap:
                for d in range(D):
                    out[t, i, d] = np.nan
                fresh = True
                continue
            for d in range(D):
                if fresh:
                    out[t, i, d] = u[t, i, d]
                else:
                    out[t, i, d] = (1.0 - k) * out[t - 1, i, d] + k * u[t, i, d]
            fresh = False
    return out


def remember(memory, mean_velocity: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """One step of ū ← (1 − κ) ū + κ u for arrays (..., N, 2), κ one number or (N,)
    (u itself where κ = 1)."""
    k = np.asarray(memory, dtype=float)
    if (k == 1.0).all():
        return velocity
    k = k[:, None] if k.ndim == 1 else k
    return (1.0 - k) * mean_velocity + k * velocity


class VelocityMemory:
    """The one-step predictor and residuals of eq. 2 with the velocity memory κ, for a model
    with ``dt``, ``meta`` and ``next_velocity(ū, p)`` (a :class:`HerdModel` or a
    :class:`~herd_ros.model.shared_law.SharedLawModel`). κ lives in ``meta`` (model file key
    ``velocity_memory``; absent = 1, the paper's model)."""

    @property
    def velocity_memory(self) -> np.ndarray:
        """κ of every agent (N,), in agents order (ones without a memory)."""
        return check_memories((self.meta or {}).get('velocity_memory', 1.0),
                              len(self.agents))

    def memory_velocities(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """u^τ = (p^{τ+1} − p^τ)/Δt and ū^τ of a run: (T, N, 2) -> two (T−1, N, 2)."""
        u = np.diff(np.asarray(positions, dtype=float), axis=0) / self.dt
        return u, memory_velocities(u, self.velocity_memory)

    def predict_one_step(self, positions: np.ndarray) -> np.ndarray:
        """Eq. 8 for every step of a run: positions (T, N, 2) -> p̂ (T−2, N, 2) for τ+2 = 2..T−1.

        p̂^{τ+2} = p^{τ+1} + Δt (a ū^τ + Σ f(p^τ) + g(p^τ))
        (ū = u^τ = (p^{τ+1} − p^τ)/Δt at κ = 1).
        """
        p = np.asarray(positions, dtype=float)
        _, ubar = self.memory_velocities(p)
        return p[1:-1] + self.dt * self.next_velocity(ubar[:-1], p[:-2])

    def residuals(self, positions: np.ndarray) -> np.ndarray:
        """w^τ = u^{τ+1} − (a ū^τ + Σ f + g) for a run: (T, N, 2) -> (T−2, N, 2)."""
        p = np.asarray(positions, dtype=float)
        u, ubar = self.memory_velocities(p)
        return u[1:] - self.next_velocity(ubar[:-1], p[:-2])
