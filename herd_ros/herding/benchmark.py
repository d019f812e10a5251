"""The herding benchmark (issue 27): herders drive a simulated herd into a goal circle.

A 150 m square field, a goal circle of radius 15 m centred 20 m from one corner. Each
episode starts the herd uniformly in a 40 m square at a random place in the far half of
the field, headings random, and the herders at random places at least 30 m from it.
**Success**: every animal inside the goal before the step budget (1 500 + 30 N steps of
1 s) runs out. Episodes are **paired**: episode k of every herder starts from the same herd
and the same herder positions (seed k), so herders are compared on the same draws.

Per setting and herder: the success rate with its Wilson 95 % interval (Wilson 1927, *JASA*
22:209), the median time to success, the herd's mean and maximum spread (the mean distance
of the animals to their centre, averaged over the episode / its maximum) and the herders'
mean path length. Plain numpy; no ROS.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from herd_ros.report.intervals import Z95, wilson_interval  # noqa: F401 (re-exported)
from herd_ros.herding.strombom import (SheepParams, ShepherdParams, herd_in_goal, move_herders,
                                       sheep_step, strombom_targets)

FIELD = 150.0
GOAL = (20.0, 20.0)
GOAL_RADIUS = 15.0
START_BOX = 40.0
FAMILIES = ('strombom', 'herd-law')


@dataclass(frozen=True)
class Setting:
    """One benchmark setting: animals, herders, the animals' noise e and cohesion n, and
    the animals' law: ``'strombom'`` (Strömbom's sheep) or ``'herd-law'`` (a law of this
    project's other family, :func:`herd_law_animals`)."""

    n_animals: int
    n_herders: int = 1
    noise: float = 0.3
    n_neighbours: int | None = None      # None: half the herd
    family: str = 'strombom'

    def __post_init__(self):
        if self.family not in FAMILIES:
            raise ValueError(f'family must be one of {FAMILIES}, got {self.family!r}')

    @property
    def neighbours(self) -> int:
        """Strömbom's n: the given cohesion, or half the herd."""
        return self.n_neighbours if self.n_neighbours is not None else max(1, self.n_animals // 2)

    @property
    def budget(self) -> int:
        """The step budget of an episode: 1500 + 30 N."""
        return 1500 + 30 * self.n_animals

    def sheep(self) -> SheepParams:
        """Strömbom's sheep of this setting (cohesion n and noise e)."""
        return SheepParams(n_neighbours=self.neighbours, e=self.noise)

    def label(self) -> str:
        """One line naming the setting (animals, herders, noise, cohesion, family)."""
        law = '' if self.family == 'strombom' else f' {self.family}'
        return (f'N={self.n_animals} herders={self.n_herders} e={self.noise:g} '
                f'n={self.neighbours}{law}')


def herd_law_animals(setting: Setting):
    """Animals of another family than Strömbom's: the shared herd law with a driver
    profile of :func:`~herd_ros.synthesis.known_truth.make_driven_truth` (damping 0.85–0.95,
    cohesion F(d) = 0.03 (d − 5)/5 e^(−d/15) within 40 m, flight H(d) = −0.25 e^(−d/15)
    from every herder within 60 m, Gaussian noise of std 0.1 × e/0.3 m/s), one agent per
    herder added as a distinguished agent. Returns the model (animals first)."""
    import dataclasses

    from herd_ros.synthesis.known_truth import make_driven_truth
    N, D = setting.n_animals, setting.n_herders
    base, _ = make_driven_truth(N, seed=setting.n_animals, noise_std=0.1 * setting.noise / 0.3)
    dogs = [f'herder_{k + 1}' for k in range(D)]
    idx = list(range(N)) + [N] * D                     # every herder is the truth's dog
    own = np.repeat(base.own_coef[idx, :1], D, axis=1)
    own[N:] = 0.0
    return dataclasses.replace(
        base, agents=base.agents[:N] + dogs, damping=base.damping[idx],
        profile_coef=base.profile_coef[idx], bases=[base.bases[i] for i in idx],
        field_u=[base.field_u[i] for i in idx], field_v=[base.field_v[i] for i in idx],
        noise_cov=base.noise_cov[idx], own_agents=dogs, own_coef=own, theta_se=None)


def animal_step(setting: Setting, P, H, dogs, sheep: SheepParams, rng, law=None):
    """One step of the animals of every episode: Strömbom's sheep (H: headings) or the herd
    law (H: velocities; p^{τ+1} = p^τ + u^τ, u^{τ+1} = the law's + noise)."""
    if setting.family == 'strombom':
        return sheep_step(P, H, dogs, sheep, rng)
    N = P.shape[1]
    pos = np.concatenate([P, dogs], axis=1)
    vel = np.concatenate([H, np.zeros_like(dogs)], axis=1)
    u = law.next_velocity(vel, pos)[:, :N]
    std = np.sqrt(law.noise_cov[:N, 0, 0])
    return P + H, u + rng.normal(size=u.shape) * std[None, :, None]


def initial_state(setting: Setting, seeds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Herd positions (S, N, 2), headings (S, N, 2) and herder positions (S, D, 2), one
    episode per seed (the same for every herder)."""
    P, H, dogs = [], [], []
    for seed in seeds:
        rng = np.random.default_rng([int(seed), 27])
        corner = rng.uniform(FIELD / 2, FIELD - START_BOX, size=2)
        p = corner + rng.uniform(0.0, START_BOX, size=(setting.n_animals, 2))
        a = rng.uniform(0, 2 * np.pi, size=setting.n_animals)
        centre = p.mean(axis=0)
        d = []
        while len(d) < setting.n_herders:
            q = rng.uniform(0.0, FIELD, size=2)
            if np.hypot(*(q - centre)) >= 30.0 + START_BOX / 2:
                d.append(q)
        P.append(p)
        H.append(np.column_stack([np.cos(a), np.sin(a)]) if setting.family == 'strombom'
                 else np.zeros((setting.n_animals, 2)))
        dogs.append(np.array(d))
    return np.array(P), np.array(H), np.array(dogs)


def strombom_herder(P, dogs, goal, sheep: SheepParams, shepherd: ShepherdParams, state):
    """Strömbom's shepherd as a herder policy: targets (S, D, 2)."""
    targets, _ = strombom_targets(P, dogs, goal, sheep, shepherd)
    return targets


def run_episodes(setting: Setting, herder, seeds, shepherd: ShepherdParams = ShepherdParams(),
                 record: int | None = None, progress=None) -> dict:
    """Run one episode per seed with ``herder`` (a policy ``(P, dogs, goal, sheep,
    shepherd, state) -> targets`` of the running episodes; ``state`` a dict it may keep
    things in, ``state['live']`` the indices of those episodes).

    Returns per episode (arrays over seeds): ``success``, ``steps`` (to success, the budget
    otherwise), ``mean_spread``, ``max_spread`` (m), ``path`` (the herders' mean path
    length, m); with ``record`` = an episode index, ``trajectory`` (its herd and herders at
    every step)."""
    seeds = list(seeds)
    sheep = setting.sheep()
    P, H, dogs = initial_state(setting, seeds)
    S = len(seeds)
    rng = np.random.default_rng([len(seeds), setting.n_animals, 2027])
    goal = np.asarray(GOAL, dtype=float)
    done = np.zeros(S, bool)
    steps = np.full(S, setting.budget)
    spread_sum = np.zeros(S)
    spread_max = np.zeros(S)
    counted = np.zeros(S)
    path = np.zeros(S)
    state: dict = {}
    law = herd_law_animals(setting) if setting.family == 'herd-law' else None
    frames = [] if record is not None else None
    for t in range(setting.budget):
        live = np.flatnonzero(~done)              # only the episodes still running
        if not len(live):
            break
        p, h, d = P[live], H[live], dogs[live]
        spread = np.sqrt(((p - p.mean(axis=1, keepdims=True)) ** 2).sum(-1)).mean(axis=1)
        spread_sum[live] += spread
        spread_max[live] = np.maximum(spread_max[live], spread)
        counted[live] += 1
        state['live'] = live
        targets = herder(p, d, goal, sheep, shepherd, state)
        new_d = move_herders(d, targets, p, sheep, shepherd, rng)
        path[live] += np.sqrt(((new_d - d) ** 2).sum(-1)).mean(axis=1)
        P[live], H[live] = animal_step(setting, p, h, d, sheep, rng, law)
        dogs[live] = new_d
        inside = herd_in_goal(P[live], goal, GOAL_RADIUS)
        steps[live[inside]] = t + 1
        done[live[inside]] = True
        if frames is not None:
            frames.append((P[record].copy(), dogs[record].copy()))
        if progress is not None:
            progress(1)
    return {'seeds': seeds, 'success': done, 'steps': steps,
            'mean_spread': spread_sum / np.maximum(counted, 1), 'max_spread': spread_max,
            'path': path, 'trajectory': frames}


def summarise(result: dict, setting: Setting) -> dict:
    """The summary.json entry of one setting and herder."""
    ok = result['success']
    k, n = int(ok.sum()), len(ok)
    return {'setting': asdict(setting) | {'neighbours': setting.neighbours,
                                          'budget_steps': setting.budget},
            'success': k / n if n else float('nan'), 'ci': list(wilson_interval(k, n)),
            'episodes': n,
            'median_time_s': float(np.median(result['steps'][ok])) if k else None,
            'mean_spread_m': float(np.mean(result['mean_spread'])),
            'max_spread_m': float(np.max(result['max_spread'])),
            'herder_path_m': float(np.mean(result['path'])),
            'seeds': [int(s) for s in result['seeds']]}
