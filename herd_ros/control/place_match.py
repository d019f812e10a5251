"""Each robot's place pull matched to how its animal keeps its place, live (issue 30: the
robots keep the herd's shape).

A law's place pull (:mod:`herd_ros.model.herd_place`, (P1)) acts at the edge of each
agent's range only, so that where the learned law already holds the herd together the
pull adds nothing. Where it does not — a young law learned from a few hours of duty-cycled
collars, whose noise carries the collars' error — the robots wander over their whole
ranges and beyond: on 12 h of duty-cycled synthetic cows their offsets from the others'
centroid spread 2.7 times as far as their animals', the herd distance +156 %. A pull
everywhere at the range's own gain halves that and holds the robots of a law that already
holds them twice as tight as their animals. Neither fixed form fits both; the fleet can
tell which it is in. As for the speed (:mod:`herd_ros.control.pace_match`), the
controller compares each robot with its animal over the same herd ticks — one moment per
robot, the spread of its place (McFadden 1989's simulated moments, the robots as the
simulation) — and corrects the share s_k of the linear pull the robot also feels inside
its range:

    r²_A = (d_A − m)ᵀ S⁻¹ (d_A − m),   r²_k = (d_k − m)ᵀ S⁻¹ (d_k − m)           (M1)
    miss_k = ½ log(Σ λ^age r²_k / Σ λ^age r²_A)                                  (M2)
    s_k ← clip(s_k + η miss_k, 0, s_max)   where |miss_k| > deadband             (M3)

d_A the animal's offset from the other animals' centroid (``/herd/poses``), d_k its
robot's from the other robots' (the robots counted in the place pull), (m, S) the place
the law holds for that animal, λ = 1 − 1/``memory``; the pull is then

    g_k = −K (d_k − m) max((1 − r₀/r)₊, s_k)                                     (M4)

(:func:`herd_ros.model.space_use_field.edge_pull` with ``share``): the edge pull alone at
s_k = 0, the pull everywhere at the range's gain at s_k = 1, stiffer above — but never so
stiff that the pull itself shakes the robot. With the law's damping a_k, its step Δt and
κ = R/(R − 1) (a robot's offset moves κ times as far as the robot), the offset under the
pull alone follows

    x^{τ+1} = x^τ + κ Δt u^τ,   u^{τ+1} = a_k u^τ − s_k K x^τ                      (M5)

whose poles are the roots of z² − (1 + a_k) z + a_k + s_k κ Δt λ_K (λ_K the largest
eigenvalue of K): stable while a_k + s_k κ Δt λ_K < 1, and damped to a modulus of √ρ at
most with s_k ≤ (ρ − a_k)/(κ Δt λ_K) (:func:`stable_shares`, ρ = ``STIFFNESS``). On
12 h of duty-cycled synthetic cows a bound of 4 alone let the shares reach it and the pull
ring (a_k + s_k κ Δt λ_K about 2): the robots 57 % faster than their animals. Both r² are
taken with the same (m, S), the law's current one: a range still growing makes the animal
look far out as much as its robot, and only their ratio moves the share. (M3) is an
integral controller on the ratio of spreads; it rests where the robot's place spreads as
its animal's, or at s = 0 where the learned law alone holds the robot tighter (the edge
pull, unchanged).

Plain numpy; no ROS. The controller's mode ``herd_model`` feeds it
(:mod:`herd_ros.nodes.herd_model_mode`, parameter ``match_place``).
"""
from __future__ import annotations

import numpy as np

from herd_ros.model.space_use_field import range_inverse

#: the samples' memory (e-folding, in herd ticks)
MEMORY = 240
#: ticks with a sample before a robot's share first moves, and ticks between corrections
MIN_SAMPLES = 60
UPDATE_EVERY = 20
#: a miss (on the spread's scale, ½ log of the ratio of mean r²) below this is left alone
DEADBAND = float(np.log(1.1))
#: η of (M3): the share's change per unit miss
RATE = 0.5
#: the range a share is kept in
BOUNDS = (0.0, 4.0)
#: ρ of (M5): the place loop's poles kept within a modulus of √ρ
STIFFNESS = 0.5


def stable_shares(damping, gain, dt: float, n_robots: int,
                  stiffness: float = STIFFNESS) -> np.ndarray:
    """The largest share of each robot's place pull for which (M5)'s poles stay within a
    modulus of √``stiffness``: (ρ − a_k)/(κ Δt λ_K) (∞ for a robot without a pull, 0 where
    the law's damping alone exceeds ρ), for dampings a (R,) and gains K (R, 2, 2)."""
    a = np.asarray(damping, dtype=float).reshape(-1)
    k = np.asarray(gain, dtype=float).reshape(-1, 2, 2)
    lam = np.linalg.eigvalsh(0.5 * (k + np.swapaxes(k, 1, 2)))[:, -1]
    kappa = n_robots / (n_robots - 1.0) if n_robots > 1 else 1.0
    with np.errstate(divide='ignore', invalid='ignore'):
        top = (float(stiffness) - a) / (kappa * float(dt) * lam)
    return np.where(lam > 0, np.maximum(np.nan_to_num(top, nan=0.0), 0.0), np.inf)


def place_r2(offsets, mean, cov) -> np.ndarray:
    """r² of (M1): (d − m)ᵀ S⁻¹ (d − m) for offsets (R, 2) and places (m (R, 2),
    S (R, 2, 2)); NaN where the offset is."""
    e = np.asarray(offsets, dtype=float) - np.asarray(mean, dtype=float)
    inv = range_inverse(np.asarray(cov, dtype=float))
    return np.einsum('ri,rij,rj->r', e, inv, e)


class PlaceMatch:
    """The place-pull shares of R robots, each matched to its animal's place spread
    (module docstring). Feed it every herd tick with :meth:`observe`; read
    :attr:`shares`."""

    def __init__(self, n_robots: int, *, memory: float = MEMORY,
                 min_samples: int = MIN_SAMPLES, update_every: int = UPDATE_EVERY,
                 deadband: float = DEADBAND, rate: float = RATE, bounds=BOUNDS):
        self.n = int(n_robots)
        self.keep = 1.0 - 1.0 / float(memory)
        self.min_samples = int(min_samples)
        self.update_every = int(update_every)
        self.deadband = float(deadband)
        self.rate = float(rate)
        self.bounds = (float(bounds[0]), float(bounds[1]))
        self.shares = np.full(self.n, self.bounds[0])
        self.updates = 0
        self.history: list[tuple[float, np.ndarray]] = []    # (t, shares) per change
        self._animal = np.zeros(self.n)      # forgetful sums of r² of the animals
        self._robot = np.zeros(self.n)       # ... and of their robots
        self.samples = np.zeros(self.n, np.int64)
        self._since = 0

    def observe(self, t: float, animal_offsets, robot_offsets, mean, cov,
                limit=None) -> bool:
        """Take one herd tick at ``t`` (s): each robot's animal's offset from the other
        animals' centroid and the robot's own from the other robots' (R, 2; NaN where
        there is none) and the places the law holds for those animals (m (R, 2), S (R, 2,
        2); a place that has not spread, S = 0, gives no sample); ``limit`` (R,), the
        largest share each may take (:func:`stable_shares`; None: :data:`BOUNDS` alone).
        Returns whether the shares changed."""
        cov = np.asarray(cov, dtype=float).reshape(self.n, 2, 2)
        spread = np.trace(cov, axis1=1, axis2=2) > 0
        ra = place_r2(np.reshape(animal_offsets, (self.n, 2)), mean, cov)
        rk = place_r2(np.reshape(robot_offsets, (self.n, 2)), mean, cov)
        ok = spread & np.isfinite(ra) & np.isfinite(rk)
        self._animal[ok] = self.keep * self._animal[ok] + ra[ok]
        self._robot[ok] = self.keep * self._robot[ok] + rk[ok]
        self.samples[ok] += 1
        top = self.bounds[1] if limit is None else np.clip(limit, *self.bounds)
        new = np.minimum(self.shares, top)      # a new law may bound a share lower
        self._since += 1
        if self._since >= self.update_every:
            self._since = 0
            ready = (self.samples >= self.min_samples) & (self._animal > 0) & \
                (self._robot > 0)
            with np.errstate(divide='ignore', invalid='ignore'):
                miss = 0.5 * np.log(self._robot / self._animal)     # > 0: the robot strays
            move = ready & np.isfinite(miss) & (np.abs(miss) > self.deadband)
            new = np.clip(new + self.rate * np.where(move, miss, 0.0), self.bounds[0], top)
        changed = bool((new != self.shares).any())
        self.shares = new
        if changed:
            self.updates += 1
            self.history.append((float(t), self.shares.copy()))
        return changed
