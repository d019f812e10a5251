"""A herder that plans with the learned herd law (issue 27): receding-horizon control by
sampling over the animals' learned response to the dog.

**Learning** (:func:`learn_response`): episodes of the animals herded by Strömbom's
shepherd with exploratory detours (the data must show the animals' response to a dog from
every side) are recorded as trajectories with the dog as an agent, and
:class:`~herd_ros.herd_dynamics.HerdDynamics` fits the shared law with the dog's **own
profile** (:mod:`herd_ros.model.shared_law`): per animal u_i^{τ+1} = a_i u_i^τ +
Σ_{j: d_ij < r} F_i(d_ij) e_ij + H_i(d_i,dog) e_i,dog (distances at τ: Schwager et al.
2007, eq. 2). The herder keeps the herd's mean law θ = (ā, F̄, H̄; the animals are
exchangeable), H̄ set to zero beyond the 95th percentile of the dog distances seen (where
the data end), and tabulates F̄ and H̄ on a fine grid of d.

**Adapting** (``adapt``, the default): in every episode θ is refitted online from the
animals' moves as the herder sees them (:mod:`~herd_ros.herding.online_response`: recursive
least squares, the offline θ its prior weighing :data:`PRIOR_STEPS` steps of the herd), so
a herd that answers the dog otherwise than the recordings is planned with its own law
within a minute or two.

**Control** (:class:`ModelHerder`), model-predictive control by sampling (the receding-
horizon scheme of Mayne et al., *Automatica* 36:789, 2000, with candidates enumerated as in
sampling-based MPC): every ``replan`` steps, each of ``candidates`` goal points for the
herders — evenly around the herd's centre at r_a √N + 5 m, and Strömbom's own target — is
scored by running the learned law (the episode's θ, as fitted: each step's forces from the
positions a step back) ``horizon`` steps with the herders walking there (with several, each
to its place on the arc below) at their speed;
the cost is the predicted mean distance of the animals to the goal plus half the largest.
The best is followed until the next plan. Several herders stand on an arc of ± 30° about
the chosen point as seen from the herd.

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
#: the online refit's prior weighs as much as this many steps of the herded herd
PRIOR_STEPS = 5.0
#: animal pairs a chunk of the planner's rollouts forms at once (memory: ~16 bytes each)
CHUNK_PAIRS = 2_000_000


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
    """The herd's mean law with the dog (module docstring): θ = [ā, c (B), h (B')] on the
    bases ``profile`` ψ (animals) and ``own_profile`` ψ' (the dog), the dog's term zero
    beyond ``reach`` (m), and the information per row of the data it was fitted on
    (:func:`~herd_ros.herding.online_response.run_information`, the online refit's prior)."""

    theta: np.ndarray
    profile: object
    own_profile: object
    reach: float
    info_per_row: np.ndarray
    choices: dict
    grid_size: int = 512

    def __post_init__(self):
        self.theta = np.asarray(self.theta, dtype=float)
        self.grid = np.linspace(0.0, max(self.profile.radius, self.own_profile.radius),
                                self.grid_size)
        self._phi = self.profile.features(self.grid)                    # (G, B)
        self._phi_dog = self.own_profile.features(self.grid) * (self.grid <= self.reach)[:, None]

    @property
    def damping(self) -> float:
        """ā."""
        return float(self.theta[0])

    def tables(self, theta=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ā (K,), F̄ (K, G), H̄ (K, G)) on :attr:`grid` for K parameter vectors (K, p)
        (default: the fitted θ)."""
        th = np.atleast_2d(self.theta if theta is None else theta)
        B = self._phi.shape[1]
        return th[:, 0], th[:, 1:1 + B] @ self._phi.T, th[:, 1 + B:] @ self._phi_dog.T

    @property
    def pooled(self) -> np.ndarray:
        """F̄(d) on :attr:`grid` (positive attracts)."""
        return self.tables()[1][0]

    @property
    def to_dog(self) -> np.ndarray:
        """H̄(d) on :attr:`grid` (negative: flight)."""
        return self.tables()[2][0]

    def _lookup(self, table, d):
        """Linear interpolation of per-herd tables (K, G) at d (K, ...) (0 beyond the grid)."""
        G = self.grid.size
        x = np.minimum(d / self.grid[-1], 2.0) * (G - 1)
        i0 = np.minimum(x.astype(np.int64), G - 2)
        w = x - i0
        # row k of the tables starts at k·G of the flattened tables
        at = i0 + (np.arange(len(table)) * G).reshape((-1,) + (1,) * (d.ndim - 1))
        flat = np.ascontiguousarray(table).ravel()
        lo, hi = flat[at], flat[at + 1]
        return np.where(x <= G - 1, lo + w * (hi - lo), 0.0)

    def velocity(self, P: np.ndarray, U: np.ndarray, dogs: np.ndarray, theta=None,
                 tables=None):
        """The law's next velocity ā U + Σ_j F̄(d_ij) e_ij + Σ_k H̄(d_ik) e_ik for K herds,
        the forces at ``P`` (K, N, 2) and the dogs ``dogs`` (K, D, 2); ``theta`` (K, p):
        each herd's own parameters (default: the fitted θ for all); ``tables``: the
        :meth:`tables` of ``theta``, when already made (a rollout makes them once)."""
        a, pooled_tab, dog_tab = self.tables(theta) if tables is None else tables
        K = P.shape[0]
        if len(a) == 1 and K > 1:
            a = np.repeat(a, K)
            pooled_tab, dog_tab = np.repeat(pooled_tab, K, 0), np.repeat(dog_tab, K, 0)
        px, py = P[..., 0], P[..., 1]
        pooled = self._pull(pooled_tab, px[:, None, :] - px[:, :, None],
                            py[:, None, :] - py[:, :, None], diagonal=True)
        dog = self._pull(dog_tab, dogs[:, None, :, 0] - px[:, :, None],
                         dogs[:, None, :, 1] - py[:, :, None])
        return a[:, None, None] * U + pooled + dog

    def _pull(self, table, ox, oy, diagonal=False):
        """Σ_j table(d_ij) e_ij over the offsets [k, i, j] = q_j − p_i (``ox``, ``oy``: each
        (K, N, M)); with ``diagonal`` the j = i terms are left out (an animal and itself).
        Per axis, the sum over j runs in order, as a reduction over a middle axis does."""
        d = np.sqrt(ox ** 2 + oy ** 2)
        if diagonal:
            n = ox.shape[1]
            d[:, np.arange(n), np.arange(n)] = np.inf
        h = self._lookup(table, d)
        d = np.where(np.isfinite(d), d, 1.0) if diagonal else np.maximum(d, 1e-9)
        # [k, j, i]: the sum over j along axis 1
        return np.stack([(h * ox / d).transpose(0, 2, 1).copy().sum(1),
                         (h * oy / d).transpose(0, 2, 1).copy().sum(1)], axis=-1)

    def step(self, P: np.ndarray, U: np.ndarray, dogs: np.ndarray, theta=None):
        """One step of the law for K herds: (P + U', U'), U' = :meth:`velocity` at P."""
        U = self.velocity(P, U, dogs, theta)
        return P + U, U


def learn_response(runs) -> LearnedResponse:
    """Fit the shared law with the dog's own profile on ``runs`` (module docstring)."""
    from herd_ros.herd_dynamics import FitOptions, HerdDynamics
    from herd_ros.herding.online_response import run_information
    dyn = HerdDynamics(options=FitOptions(
        law='shared', own_agents=['dog'], terms=['damping+interactions'], grids=[],
        field='fitted', noise='gaussian', memories=(), alignment='off', noise_scale=1.0)).fit(runs)
    m = dyn.model
    animals = slice(0, m.n_agents - 1)                              # the dog is last
    p = np.concatenate([r.positions for r in runs])
    seen = np.sqrt(((p[:, :-1] - p[:, -1:]) ** 2).sum(-1))
    reach = float(np.percentile(seen[np.isfinite(seen)], 95))
    theta = np.concatenate([[m.damping[animals].mean()], m.profile_coef[animals].mean(axis=0),
                            m.own_coef[animals, 0].mean(axis=0)])
    info, rows = run_information(runs, m.profile, m.own_profile)
    return LearnedResponse(theta, m.profile, m.own_profile, reach, info / max(rows, 1),
                           dyn.choices)


def learn_model_herder(n_animals: int, n_robots: int) -> 'ModelHerder':
    """The model herder of a herd of ``n_animals`` and ``n_robots`` herders: the response
    learned from simulated recordings (:func:`record_episodes`, :func:`learn_response`)."""
    from herd_ros.herding.benchmark import Setting
    return ModelHerder(learn_response(record_episodes(Setting(n_animals, n_robots))))


def learn_model_herder_into(conn, n_animals: int, n_robots: int):
    """:func:`learn_model_herder` in a worker process: sends ``('herder', ModelHerder)`` or
    ``('error', message)`` through the pipe end ``conn``."""
    try:
        conn.send(('herder', learn_model_herder(n_animals, n_robots)))
    except Exception as exc:                # noqa: BLE001 (reported by the node)
        conn.send(('error', f'{type(exc).__name__}: {exc}'))
    finally:
        conn.close()


class ModelHerder:
    """Receding-horizon herder over a :class:`LearnedResponse` (module docstring); a policy
    for :func:`~herd_ros.herding.benchmark.run_episodes`. With ``adapt`` the response is
    refitted online in every episode (:class:`~herd_ros.herding.online_response
    .OnlineResponse`, the learned θ its prior, weighing ``prior_steps`` steps)."""

    def __init__(self, response: LearnedResponse, candidates: int = 12, horizon: int = 25,
                 replan: int = 5, arc_deg: float = 30.0, adapt: bool = True,
                 prior_steps: float = PRIOR_STEPS):
        self.response, self.candidates = response, int(candidates)
        self.horizon, self.replan, self.arc = int(horizon), int(replan), np.radians(arc_deg)
        self.adapt, self.prior_steps = bool(adapt), float(prior_steps)

    def _observe(self, P, dogs, state):
        """Keep the live episodes' last two states (animals and herders) and, with
        ``adapt``, feed their last displacement to the online fit: u^{τ+1} = p^{τ+2} −
        p^{τ+1} on u^τ and the forces at τ (:func:`~herd_ros.herding.online_response
        .response_rows`). Returns the states at τ+1 (the previous call)."""
        from herd_ros.herding.online_response import OnlineResponse, response_rows
        live = state['live']
        S, N, _ = P.shape
        now = np.concatenate([P, dogs], axis=1)
        if 'online' not in state:             # every episode is live at the first call
            r = self.response
            state['online'] = OnlineResponse(r.theta, r.info_per_row, len(live), 2 * N,
                                             self.prior_steps)
            state['history'] = np.repeat(now[:, None], 2, axis=1)     # [τ+1, τ]
            state['calls'] = np.zeros(len(live), np.int64)
        hist, calls = state['history'], state['calls']
        last, before = hist[live, 0], hist[live, 1]
        ready = calls[live] >= 2
        if self.adapt and ready.any():
            k = np.flatnonzero(ready)
            x = response_rows(before[k, :N], last[k, :N] - before[k, :N], before[k, N:],
                              self.response.profile, self.response.own_profile)
            y = P[k] - last[k, :N]
            state['online'].update(live[k], x.reshape(len(k), -1, x.shape[-1]),
                                   y.reshape(len(k), -1))
        hist[live, 1], hist[live, 0] = last, now
        calls[live] += 1
        return last

    def __call__(self, P, dogs, goal, sheep, shepherd, state):
        """Each herder's target (S, D, 2) for the live episodes, replanned every few steps."""
        live = state['live']
        last = self._observe(P, dogs, state)
        t = state.setdefault('t', 0)
        state['t'] = t + 1
        plans = state.setdefault('plans', {})
        if t % self.replan and all(int(s) in plans for s in live):
            return self._formation(np.stack([plans[int(s)] for s in live]),
                                   P.mean(axis=1), dogs.shape[1])
        S, N, _ = P.shape
        gcm = P.mean(axis=1)
        ang = np.linspace(0, 2 * np.pi, self.candidates, endpoint=False)
        ring = sheep.r_a * np.sqrt(N) + 5.0
        cands = gcm[:, None, :] + ring * np.stack([np.cos(ang), np.sin(ang)], -1)[None]
        strom, _ = strombom_targets(P, dogs[:, :1], goal, sheep, shepherd)
        cands = np.concatenate([cands, strom], axis=1)              # (S, C, 2)
        C, D = cands.shape[1], dogs.shape[1]
        # every herder walks to its place in the formation about the candidate point
        targets = self._formation(cands.reshape(S * C, 2), np.repeat(gcm, C, axis=0), D)
        cost = np.empty(S * C)
        # in chunks of episodes: a chunk's rollout forms about CHUNK_PAIRS animal pairs
        step = max(1, int(CHUNK_PAIRS // (C * N * N)))
        theta = state['online'].theta[live]
        for a in range(0, S, step):
            e = slice(a, min(a + step, S))
            k = slice(e.start * C, e.stop * C)
            cost[k] = self._rollout_cost(P[e], last[e], dogs[e], theta[e], targets[k], goal,
                                         shepherd.speed)
        best = cands[np.arange(S), np.argmin(cost.reshape(S, C), axis=1)]
        for k, s in enumerate(live):
            plans[int(s)] = best[k]
        return self._formation(best, gcm, D)

    def _rollout_cost(self, P, last, dogs, theta, targets, goal, speed):
        """The cost of each candidate (S·C,) of S episodes: the learned law run ``horizon``
        steps as fitted (u^{τ+1} = ā u^τ + forces at τ: the herd and the herders a step
        back; ``last`` the animals and herders at the previous step) with every herder
        walking to its ``targets`` (S·C, D, 2) at ``speed``; the predicted mean distance of
        the animals to the goal plus half the largest."""
        S, N, _ = P.shape
        C = len(targets) // S

        def each(a):                                                # (S, ...) -> (S·C, ...)
            return np.repeat(a[:, None], C, axis=1).reshape((S * C,) + a.shape[1:])

        Pk, Uk = each(P), each(P - last[:, :N])
        dk, d_back = each(dogs), each(last[:, N:])
        tables = tuple(each(t) for t in self.response.tables(theta))   # θ's, made once
        for _ in range(self.horizon):
            Uk = self.response.velocity(Pk - Uk, Uk, d_back, tables=tables)
            Pk = Pk + Uk
            gap = targets - dk
            dist = np.sqrt((gap ** 2).sum(-1, keepdims=True))
            d_back = dk
            dk = dk + np.minimum(speed, dist) * gap / np.maximum(dist, 1e-9)
        d = np.sqrt(((Pk - np.asarray(goal)) ** 2).sum(-1))
        return d.mean(-1) + 0.5 * d.max(-1)

    def _formation(self, points, gcm, D):
        """The herders' targets: the planned point, or with D herders an arc of ± arc about
        it as seen from the herd's centre ``gcm`` (one per point)."""
        if D == 1:
            return points[:, None, :]
        rel = points - gcm
        a = np.linspace(-self.arc, self.arc, D)
        c, s = np.cos(a), np.sin(a)
        rot = np.stack([rel[:, None, 0] * c - rel[:, None, 1] * s,
                        rel[:, None, 0] * s + rel[:, None, 1] * c], axis=-1)
        return gcm[:, None, :] + rot
