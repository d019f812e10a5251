"""A herder that plans with the learned herd law (issue 27): receding-horizon control by
sampling over the animals' learned response to the dog.

**Learning** (:func:`learn_response`): episodes of the animals herded by Strömbom's
shepherd with exploratory detours (the data must show the animals' response to a dog from
every side) are recorded as trajectories with the dog as an agent, and
:class:`~herd_ros.herd_dynamics.HerdDynamics` fits the shared law with the dog's **own
profile** (:mod:`herd_ros.model.shared_law`): per animal u_i^{τ+1} = a_i u_i^τ +
Σ_{j: d_ij < r} F_i(d_ij) e_ij + H_i(d_i,dog) e_i,dog. The herder keeps the herd's mean law
(ā, F̄, H̄; the animals are exchangeable), H̄ set to zero beyond the 95th percentile of the
dog distances seen (where the data end), and tabulates F̄ and H̄ on a fine grid of d.

**Control** (:class:`ModelHerder`), model-predictive control by sampling (the receding-
horizon scheme of Mayne et al., *Automatica* 36:789, 2000, with candidates enumerated as in
sampling-based MPC): every ``replan`` steps, each of ``candidates`` goal points for the
herders — evenly around the herd's centre at r_a √N + 5 m, and Strömbom's own target — is
scored by running the learned law ``horizon`` steps with the herders walking there at
their speed; the cost is the predicted mean distance of the animals to the goal plus half
the largest. The best is followed until the next plan. Several herders stand on an arc of
± 30° about the chosen point as seen from the herd.

Plain numpy; no ROS.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from herd_ros.herding.benchmark import GOAL, Setting, initial_state
from herd_ros.herding.strombom import (ShepherdParams, move_herders, sheep_step,
                                       strombom_targets)

#: seeds of the learning episodes (never those of the benchmark: 0 … S−1)
LEARNING_SEEDS = range(100_000, 100_030)


def record_episodes(setting: Setting, seeds=LEARNING_SEEDS, steps: int = 600,
                    explore: float = 0.3, sheep=None) -> list:
    """Episodes of Strömbom's shepherd, a share ``explore`` of each 50-step stretch spent
    walking to a random point about the herd instead: :class:`HerdTrajectory` runs with
    the animals and 'dog' (the first herder) on a 1 s clock. ``sheep``: other animal
    parameters than the setting's (a law the herder was not told)."""
    from herd_ros.trajectory import HerdTrajectory
    sheep = sheep or setting.sheep()
    dog = ShepherdParams()
    seeds = list(seeds)
    P, H, dogs = initial_state(setting, seeds)
    rng = np.random.default_rng([len(seeds), setting.n_animals, 41])
    out = np.empty((steps, len(seeds), setting.n_animals + 1, 2))
    wander, use = dogs.copy(), np.zeros((len(seeds), 1, 1), bool)
    for t in range(steps):
        out[t, :, :-1], out[t, :, -1] = P, dogs[:, 0]
        target, _ = strombom_targets(P, dogs, GOAL, sheep, dog)
        if t % 50 == 0:
            wander = P.mean(axis=1, keepdims=True) + rng.uniform(-40, 40, size=dogs.shape)
            use = (rng.random(len(seeds)) < explore)[:, None, None]
        new_dogs = move_herders(dogs, np.where(use, wander, target), P, sheep, dog, rng)
        P, H = sheep_step(P, H, dogs, sheep, rng)
        dogs = new_dogs
    agents = [f'animal_{i + 1}' for i in range(setting.n_animals)] + ['dog']
    times = np.arange(steps, dtype=float)
    return [HerdTrajectory(times, agents, out[:, k]) for k in range(len(seeds))]


@dataclass
class LearnedResponse:
    """The herd's mean law with the dog (module docstring), tabulated on ``grid`` (m)."""

    damping: float
    grid: np.ndarray
    pooled: np.ndarray          # F̄(d) on grid (positive attracts)
    to_dog: np.ndarray          # H̄(d) on grid (negative: flight)
    choices: dict

    def step(self, P: np.ndarray, U: np.ndarray, dogs: np.ndarray):
        """One step of the law for K herds (K, N, 2) with their dogs (K, D, 2)."""
        off = P[:, None, :, :] - P[:, :, None, :]                  # [k, i, j] = p_j − p_i
        d = np.sqrt((off ** 2).sum(-1))
        n = P.shape[1]
        d[:, np.arange(n), np.arange(n)] = np.inf
        f = np.interp(d, self.grid, self.pooled, right=0.0)
        pooled = (f[..., None] * off / np.where(np.isfinite(d), d, 1.0)[..., None]).sum(2)
        to = dogs[:, None, :, :] - P[:, :, None, :]                 # (K, N, D, 2)
        dd = np.sqrt((to ** 2).sum(-1))
        h = np.interp(dd, self.grid, self.to_dog, right=0.0)
        dog = (h[..., None] * to / np.maximum(dd, 1e-9)[..., None]).sum(2)
        U = self.damping * U + pooled + dog
        return P + U, U


def learn_response(runs) -> LearnedResponse:
    """Fit the shared law with the dog's own profile on ``runs`` (module docstring)."""
    from herd_ros.herd_dynamics import FitOptions, HerdDynamics
    dyn = HerdDynamics(options=FitOptions(
        law='shared', own_agents=['dog'], terms=['damping+interactions'], grids=[],
        field='fitted', noise='gaussian', memories=(), alignment='off', noise_scale=1.0)).fit(runs)
    m = dyn.model
    animals = slice(0, m.n_agents - 1)                              # the dog is last
    p = np.concatenate([r.positions for r in runs])
    seen = np.sqrt(((p[:, :-1] - p[:, -1:]) ** 2).sum(-1))
    reach = float(np.percentile(seen[np.isfinite(seen)], 95))
    grid = np.linspace(0.0, max(m.profile.radius, m.own_profile.radius), 512)
    pooled = m.profile.features(grid) @ m.profile_coef[animals].mean(axis=0)
    to_dog = m.own_profile.features(grid) @ m.own_coef[animals, 0].mean(axis=0)
    to_dog[grid > reach] = 0.0                                      # where the data end
    return LearnedResponse(float(m.damping[animals].mean()), grid, pooled, to_dog,
                           dyn.choices)


class ModelHerder:
    """Receding-horizon herder over a :class:`LearnedResponse` (module docstring); a policy
    for :func:`~herd_ros.herding.benchmark.run_episodes`."""

    def __init__(self, response: LearnedResponse, candidates: int = 12, horizon: int = 25,
                 replan: int = 5, arc_deg: float = 30.0):
        self.response, self.candidates = response, int(candidates)
        self.horizon, self.replan, self.arc = int(horizon), int(replan), np.radians(arc_deg)

    def __call__(self, P, dogs, goal, sheep, shepherd, state):
        """Each herder's target (S, D, 2) for the live episodes, replanned every few steps."""
        live = state['live']
        t = state.setdefault('t', 0)
        state['t'] = t + 1
        plans = state.setdefault('plans', {})
        prev = state.get('previous', {})
        state['previous'] = {int(s): P[k].copy() for k, s in enumerate(live)}
        if t % self.replan and all(int(s) in plans for s in live):
            return self._formation(np.stack([plans[int(s)] for s in live]), P, dogs.shape[1])
        S, N, _ = P.shape
        gcm = P.mean(axis=1)
        ang = np.linspace(0, 2 * np.pi, self.candidates, endpoint=False)
        ring = sheep.r_a * np.sqrt(N) + 5.0
        cands = gcm[:, None, :] + ring * np.stack([np.cos(ang), np.sin(ang)], -1)[None]
        strom, _ = strombom_targets(P, dogs[:, :1], goal, sheep, shepherd)
        cands = np.concatenate([cands, strom], axis=1)              # (S, C, 2)
        C = cands.shape[1]
        U0 = np.stack([P[k] - prev[int(s)] if int(s) in prev else np.zeros((N, 2))
                       for k, s in enumerate(live)])
        Pk = np.repeat(P[:, None], C, axis=1).reshape(S * C, N, 2)
        Uk = np.repeat(U0[:, None], C, axis=1).reshape(S * C, N, 2)
        dk = np.repeat(dogs[:, None, :1], C, axis=1).reshape(S * C, 1, 2)
        target = cands.reshape(S * C, 1, 2)
        for _ in range(self.horizon):
            Pk, Uk = self.response.step(Pk, Uk, dk)
            gap = target - dk
            dist = np.sqrt((gap ** 2).sum(-1, keepdims=True))
            dk = dk + np.minimum(shepherd.speed, dist) * gap / np.maximum(dist, 1e-9)
        d = np.sqrt(((Pk - np.asarray(goal)) ** 2).sum(-1)).reshape(S, C, N)
        cost = d.mean(-1) + 0.5 * d.max(-1)
        best = cands[np.arange(S), np.argmin(cost, axis=1)]
        for k, s in enumerate(live):
            plans[int(s)] = best[k]
        return self._formation(best, P, dogs.shape[1])

    def _formation(self, points, P, D):
        """The herders' targets: the planned point, or with D herders an arc of ± arc about
        it as seen from the herd's centre."""
        if D == 1:
            return points[:, None, :]
        gcm = P.mean(axis=1)
        rel = points - gcm
        a = np.linspace(-self.arc, self.arc, D)
        c, s = np.cos(a), np.sin(a)
        rot = np.stack([rel[:, None, 0] * c - rel[:, None, 1] * s,
                        rel[:, None, 0] * s + rel[:, None, 1] * c], axis=-1)
        return gcm[:, None, :] + rot
