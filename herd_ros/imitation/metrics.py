"""Imitation metrics of Rahman, White et al. (ACC 2023): MAE, AMD(t), AVD(t).

* MAE — the one-step loss: mean over samples of the Euclidean velocity error
  ``(1/S) Σ_s ‖v̂_s − v_s‖`` (m/s).
* AMD(t) — average mean distance of a swarm at time t: the mean over agents of each agent's
  mean distance to the others, ``(1/N) Σ_i (1/(N−1)) Σ_{j≠i} ‖p_i − p_j‖`` (m) — how spread out
  the swarm is.
* AVD(t) — average velocity difference: the same with velocities,
  ``(1/N) Σ_i (1/(N−1)) Σ_{j≠i} ‖v_i − v_j‖`` (m/s) — how well the swarm is aligned.

The paper compares AMD(t) and AVD(t) of the original swarm with those of the imitation
simulated from the same initial states; :func:`relative_deviation` (largest pointwise relative
gap of the run-averaged curves, optionally against a floor) and
:func:`integrated_relative_deviation` (the gap summed over the run relative to the original's)
are the comparisons used in the acceptance tests.
(The paper's wording is terse; this is our reading of it: swarm-level statistics, computed for
each swarm separately, not distances between matched original/imitation agents.)
"""
from __future__ import annotations

import numpy as np


def mae(predicted: np.ndarray, observed: np.ndarray) -> float:
    """Mean Euclidean error of (..., 2) velocity vectors (m/s)."""
    return float(np.mean(np.linalg.norm(np.asarray(predicted) - np.asarray(observed), axis=-1)))


def _mean_pairwise_norm(x: np.ndarray) -> np.ndarray:
    n = x.shape[-2]
    d = np.linalg.norm(x[..., :, None, :] - x[..., None, :, :], axis=-1)
    return d.sum(axis=(-1, -2)) / (n * (n - 1))


def amd(positions: np.ndarray) -> np.ndarray:
    """AMD(t) of positions (..., T, N, 2) -> (..., T) metres."""
    return _mean_pairwise_norm(np.asarray(positions, dtype=float))


def avd(velocities: np.ndarray) -> np.ndarray:
    """AVD(t) of velocities (..., T, N, 2) -> (..., T) m/s."""
    return _mean_pairwise_norm(np.asarray(velocities, dtype=float))


def relative_deviation(imitation: np.ndarray, original: np.ndarray, floor: float = 0.0) -> float:
    """max_t |imitation(t) − original(t)| / max(|original(t)|, floor) of two (T,) curves.

    ``floor`` (same unit as the curves) keeps the ratio meaningful where the original
    decays toward zero — e.g. AVD(t) of a swarm that has aligned, where a pointwise ratio
    compares differences of centimetres per second. 0 gives the plain pointwise ratio.
    """
    original = np.asarray(original, dtype=float)
    scale = np.maximum(np.abs(original), floor)
    return float(np.max(np.abs(np.asarray(imitation) - original) / scale))


def integrated_relative_deviation(imitation: np.ndarray, original: np.ndarray) -> float:
    """Σ_t |imitation(t) − original(t)| / Σ_t |original(t)| of two (T,) curves on one uniform
    time grid: the gap over the run as a fraction of the original's (an L1 ratio)."""
    original = np.asarray(original, dtype=float)
    return float(np.sum(np.abs(np.asarray(imitation) - original)) / np.sum(np.abs(original)))


def compare_with_imitation(policy, runs) -> dict:
    """AMD(t) and AVD(t) of recorded runs vs the imitation simulated from the same states.

    Each run's imitation starts at the recorded positions q^1 with previous velocities
    y^0 = (q^1 − q^0)/Δt and is rolled forward T − 1 steps with ``policy`` (noise-free). The
    recorded velocities are forward differences of the recorded positions, so with noisy
    positions the recorded AVD carries the noise (√2σ/Δt per component) too.

    Returns:
        dict of (T−2,) run-averaged curves ``time``, ``amd_data``, ``amd_imitation``,
        ``avd_data``, ``avd_imitation`` and the per-run imitation ``positions`` list.
    """
    from herd_ros.imitation.boids import simulate

    T = min(r.n_steps for r in runs)
    amd_d, amd_i, avd_d, avd_i, sims = [], [], [], [], []
    for r in runs:
        q = np.asarray(r.positions[:T], dtype=float)
        y = np.diff(q, axis=0) / r.dt
        pos, vel = simulate(policy, q[1][None], y[0][None], T - 1)
        sims.append(pos[0])
        amd_d.append(amd(q[1:-1]))
        amd_i.append(amd(pos[0][:-1]))
        avd_d.append(avd(y[1:]))
        avd_i.append(avd(vel[0][:-1]))
    t = np.asarray(runs[0].times[1:T - 1], dtype=float)
    return {'time': t, 'amd_data': np.mean(amd_d, axis=0), 'amd_imitation': np.mean(amd_i, 0),
            'avd_data': np.mean(avd_d, axis=0), 'avd_imitation': np.mean(avd_i, axis=0),
            'positions': sims}
