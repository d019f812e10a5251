"""Strömbom's sheep and shepherd (Strömbom et al. 2014, *J. R. Soc. Interface*
11:20140719), vectorised over many independent episodes at once.

**Sheep** i, one step (all unit vectors; the paper's weights as defaults)::

    H'_i = h Ĥ_i + c Ĉ_i + ρ_a R̂^a_i + ρ_s R̂^s_i + e ε̂_i,    P'_i = P_i + δ Ĥ'_i

* Ĥ_i its previous heading (inertia);
* C_i = LCM_i − P_i, the local centre of mass of its ``n`` nearest neighbours (cohesion:
  n ≈ half the herd is the paper's cohesive flock, n of a few is short-range);
* R^a_i = Σ_{j: ‖P_i − P_j‖ < r_a} (P_i − P_j)/‖P_i − P_j‖, repulsion from crowding;
* R^s_i = Σ_{dogs within r_s} (P_i − S)/‖P_i − S‖, flight from the dog(s);
* ε_i a random direction, weight e (the noise the benchmark varies).

A sheep with no dog within r_s grazes: it stays put, except with probability ``graze``
per step when it takes the step above without the dog's term.

**Shepherd** (the paper's heuristic), speed δ_s = 1.5 δ: with Γ the herd's centre of mass,
D the goal and f(N) = r_a N^(2/3),

* if every sheep is within f(N) of Γ, **drive**: go to P_d = Γ + r_a √N (Γ − D)/‖Γ − D‖,
  behind the herd as seen from the goal;
* else **collect**: go to P_c = A + r_a (A − Γ)/‖A − Γ‖ behind the sheep A furthest from Γ;
* stand still when within 3 r_a of any sheep (not to split the herd); a small noise e_s.

With several herders (an extension: the paper has one) herder k collects the k-th furthest
sheep, and they drive from points spread on an arc behind the herd (±30°, in the manner of
Pierson & Schwager, IEEE T-RO 34:1069, 2018).

Plain numpy; no ROS.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SheepParams:
    """Strömbom's sheep (module docstring); lengths in m, one step per second."""

    n_neighbours: int
    r_a: float = 2.0
    r_s: float = 65.0
    h: float = 0.5
    c: float = 1.05
    rho_a: float = 2.0
    rho_s: float = 1.0
    e: float = 0.3
    delta: float = 1.0
    graze: float = 0.05


@dataclass(frozen=True)
class ShepherdParams:
    """Strömbom's shepherd: ``speed`` (m per step), noise ``e``, stop within
    ``stop_factor`` × r_a of a sheep, drive from an arc of ± ``arc_deg`` with several."""

    speed: float = 1.5
    e: float = 0.3
    stop_factor: float = 3.0
    arc_deg: float = 30.0


def _unit(v: np.ndarray) -> np.ndarray:
    """v / |v| along the last axis (0 where v = 0)."""
    n = np.sqrt((v ** 2).sum(-1, keepdims=True))
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def _random_directions(rng, shape) -> np.ndarray:
    a = rng.uniform(0.0, 2 * np.pi, size=shape)
    return np.stack([np.cos(a), np.sin(a)], axis=-1)


def sheep_step(P: np.ndarray, H: np.ndarray, dogs: np.ndarray, params: SheepParams,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One step of every sheep of every episode (module docstring).

    Args:
        P, H: (S, N, 2) positions and headings; ``dogs`` (S, D, 2).
    Returns:
        (P', H').
    """
    S, N, _ = P.shape
    off = P[:, :, None, :] - P[:, None, :, :]                  # [s, i, j] = P_i − P_j
    d = np.sqrt((off ** 2).sum(-1))
    d_self = d + np.eye(N)[None] * 1e12
    k = int(min(max(params.n_neighbours, 1), N - 1))
    near = np.argpartition(d_self, k - 1, axis=-1)[..., :k]     # (S, N, k)
    lcm = P[np.arange(S)[:, None, None], near].mean(axis=2)     # (S, N, 2)
    C = _unit(lcm - P)
    crowd = (d_self < params.r_a)[..., None]
    Ra = _unit((np.where(crowd, _unit(off), 0.0)).sum(axis=2))
    to_dog = P[:, :, None, :] - dogs[:, None, :, :]             # (S, N, D, 2)
    dd = np.sqrt((to_dog ** 2).sum(-1))
    seen = dd < params.r_s
    Rs = _unit(np.where(seen[..., None], _unit(to_dog), 0.0).sum(axis=2))
    eps = _random_directions(rng, (S, N))
    alerted = seen.any(axis=-1)                                 # (S, N)
    Hn = (params.h * _unit(H) + params.c * C + params.rho_a * Ra
          + params.rho_s * Rs * alerted[..., None] + params.e * eps)
    moves = alerted | (rng.random((S, N)) < params.graze)
    Hn = np.where(moves[..., None], _unit(Hn), H)
    Pn = P + np.where(moves[..., None], params.delta * Hn, 0.0)
    return Pn, Hn


def herd_is_gathered(P: np.ndarray, r_a: float, dist: np.ndarray | None = None) -> np.ndarray:
    """Every sheep within f(N) = r_a N^(2/3) of the centre of mass, per episode (S,);
    ``dist`` (S, N): the sheep's distances to it, when already known."""
    N = P.shape[1]
    if dist is None:
        dist = np.sqrt(((P - P.mean(axis=1, keepdims=True)) ** 2).sum(-1))
    return (dist <= r_a * N ** (2.0 / 3.0)).all(axis=1)


def strombom_targets(P: np.ndarray, dogs: np.ndarray, goal, sheep: SheepParams,
                     shepherd: ShepherdParams) -> tuple[np.ndarray, np.ndarray]:
    """Where each herder heads (S, D, 2) and whether the episode is driving (S,)."""
    S, N, _ = P.shape
    D = dogs.shape[1]
    gcm = P.mean(axis=1)                                        # (S, 2)
    goal = np.asarray(goal, dtype=float)
    away = _unit(gcm - goal)                                    # from the goal, through Γ
    dist = np.sqrt(((P - gcm[:, None, :]) ** 2).sum(-1))        # (S, N)
    driving = herd_is_gathered(P, sheep.r_a, dist)
    angles = np.radians(np.linspace(-shepherd.arc_deg, shepherd.arc_deg, D)) if D > 1 \
        else np.zeros(1)
    cos, sin = np.cos(angles), np.sin(angles)
    arc = np.stack([away[:, None, 0] * cos - away[:, None, 1] * sin,
                    away[:, None, 0] * sin + away[:, None, 1] * cos], axis=-1)   # (S, D, 2)
    drive = gcm[:, None, :] + sheep.r_a * np.sqrt(N) * arc
    order = np.argsort(-dist, axis=1)[:, :D]                    # the D furthest
    far = np.take_along_axis(P, order[..., None], axis=1)       # (S, D, 2)
    collect = far + sheep.r_a * _unit(far - gcm[:, None, :])
    return np.where(driving[:, None, None], drive, collect), driving


def herder_velocities(dogs: np.ndarray, targets: np.ndarray, P: np.ndarray,
                      sheep: SheepParams, shepherd: ShepherdParams, rng: np.random.Generator,
                      period: float = 1.0) -> np.ndarray:
    """Each herder's velocity (S, D, 2), m per step: toward its target at ``speed`` (with
    noise e_s), no farther than the target in ``period`` steps; zero within ``stop_factor``
    r_a of a sheep (not to split the herd)."""
    step = _unit(_unit(targets - dogs) + shepherd.e * _random_directions(rng, dogs.shape[:2]))
    gap = np.sqrt(((targets - dogs) ** 2).sum(-1, keepdims=True))
    close = (np.sqrt(((dogs[:, :, None, :] - P[:, None, :, :]) ** 2).sum(-1))
             < shepherd.stop_factor * sheep.r_a).any(axis=-1)
    v = np.minimum(shepherd.speed, gap / period) * step
    return np.where(close[..., None], 0.0, v)


def move_herders(dogs: np.ndarray, targets: np.ndarray, P: np.ndarray, sheep: SheepParams,
                 shepherd: ShepherdParams, rng: np.random.Generator) -> np.ndarray:
    """Each herder one step of at most ``speed`` toward its target (with noise e_s); it
    stands still within ``stop_factor`` r_a of a sheep (:func:`herder_velocities`)."""
    return dogs + herder_velocities(dogs, targets, P, sheep, shepherd, rng)


def herd_in_goal(P: np.ndarray, goal, radius: float) -> np.ndarray:
    """Every sheep within ``radius`` of ``goal``, per episode: P (S, N, 2) -> (S,) (NaN
    positions count as outside)."""
    d = np.sqrt(((np.asarray(P, dtype=float) - np.asarray(goal, dtype=float)) ** 2).sum(-1))
    return (d <= radius).all(axis=-1)
