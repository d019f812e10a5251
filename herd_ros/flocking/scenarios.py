"""The report's flocking experiments and the simulation loop that runs them.

Setting (the report, doc/formats.md): N agents (50) placed uniformly at random in [0, 75]² m,
at rest; the target (γ-agent) starts at (20, 50) m and moves at 10 m/s along +x; dt 0.02 s.

Scenarios (``SCENARIOS``):

* ``free``: no obstacle.
* ``obstacle``: a circle at (100, 50), radius 10 m, right on the target's path.
* ``obstacles``: three circles, (90, 42, 6), (130, 58, 8), (170, 46, 7) (x, y, r; m).
* ``moving-obstacle``: a circle of radius 8 m starting at (100, 10) and moving at 5 m/s
  along +y, so it crosses the target's path where the flock meets it (about t = 8 s).
* ``adversarial-static``: k of N agents (default 5) stay where they were placed.
* ``adversarial-random``: k agents apply accelerations uniform in [−150, 150]² m/s² each step.
* ``turning``: the target turns on a circle of radius 50 m at 10 m/s, starting at (20, 50)
  heading +x (centre (20, 100), counter-clockwise).

Integration is semi-implicit (symplectic) Euler: ``p ← p + u h``, then ``q ← q + p h``, with
the control recomputed every ``h = dt / substeps`` (zero-order hold in between). Metrics and
recordings are taken every ``dt`` (the report's 0.02 s). ``substeps`` defaults to 2 (control
at 100 Hz): at h = 0.02 s the discrete loop sits at its stability edge when the flock crowds
against an obstacle — velocity consensus has gain c2α·λmax(L) with up to ~28 neighbours at
a_ij ≈ 1 (c2α·28 ≈ 125 /s), and explicit Euler needs gain·h < 2 — and we measured speeds
oscillating at ±300 m/s and one agent pushed into the obstacle (local-com, obstacle, seed 2).
At h = 0.01 s all 90 obstacle runs (3 scenarios × 3 γ modes × 10 seeds) keep ≥ 4.2 m of
clearance.
The other agents cannot tell adversaries from honest agents: adversaries are neighbours like
any other and count in the centre of mass of the global/local-CoM feedback.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.flocking.metrics import METRIC_NAMES, step_metrics
from herd_ros.flocking.olfati_saber import (CircularObstacles, FlockingParams,
                                            flocking_acceleration, neighbour_pairs)

SCENARIOS = ('free', 'obstacle', 'obstacles', 'moving-obstacle', 'adversarial-static',
             'adversarial-random', 'turning')

DT = 0.02                    # s, the report's step
PLACEMENT_BOX = 75.0         # m, agents uniform in [0, 75]²
TARGET_START = (20.0, 50.0)  # m
TARGET_SPEED = 10.0          # m/s
TURN_RADIUS = 50.0           # m
DEFAULT_SUBSTEPS = 2         # control/integration steps per dt (see the module docstring)
RANDOM_INPUT_BOUND = 150.0   # m/s², adversarial-random inputs in [−150, 150]
DEFAULT_ADVERSARIES = 5


def straight_target(t: float):
    """q_r(t), p_r(t): from (20, 50) at 10 m/s along +x."""
    return (np.array([TARGET_START[0] + TARGET_SPEED * t, TARGET_START[1]]),
            np.array([TARGET_SPEED, 0.0]))


def turning_target(t: float):
    """q_r(t), p_r(t) on the circle of radius 50 m about (20, 100), at 10 m/s, starting at
    (20, 50) heading +x (angular rate ω = v/R = 0.2 rad/s)."""
    w = TARGET_SPEED / TURN_RADIUS
    x0, y0 = TARGET_START
    q = np.array([x0 + TURN_RADIUS * math.sin(w * t), y0 + TURN_RADIUS * (1 - math.cos(w * t))])
    p = TARGET_SPEED * np.array([math.cos(w * t), math.sin(w * t)])
    return q, p


@dataclass
class Scenario:
    """One experiment: target motion, obstacles, adversaries and the default duration."""

    name: str
    target: Callable[[float], tuple[np.ndarray, np.ndarray]] = straight_target
    obstacles: CircularObstacles = field(default_factory=CircularObstacles)
    adversary_kind: str | None = None   # None, 'static' or 'random'
    n_adversaries: int = 0
    duration: float = 20.0               # s


def make_scenario(name: str, n_adversaries: int = DEFAULT_ADVERSARIES) -> Scenario:
    """The scenario called ``name`` (one of :data:`SCENARIOS`)."""
    if name == 'free':
        return Scenario(name)
    if name == 'obstacle':
        return Scenario(name, obstacles=CircularObstacles([[100.0, 50.0]], [10.0]))
    if name == 'obstacles':
        return Scenario(name, obstacles=CircularObstacles(
            [[90.0, 42.0], [130.0, 58.0], [170.0, 46.0]], [6.0, 8.0, 7.0]), duration=22.0)
    if name == 'moving-obstacle':
        return Scenario(name, obstacles=CircularObstacles([[100.0, 10.0]], [8.0],
                                                          [[0.0, 5.0]]))
    if name == 'adversarial-static':
        return Scenario(name, adversary_kind='static', n_adversaries=n_adversaries)
    if name == 'adversarial-random':
        return Scenario(name, adversary_kind='random', n_adversaries=n_adversaries)
    if name == 'turning':
        return Scenario(name, target=turning_target, duration=2 * math.pi * TURN_RADIUS
                        / TARGET_SPEED)
    raise HerdInputError(f'scenario must be one of {", ".join(SCENARIOS)} (got {name!r})')


@dataclass
class FlockRun:
    """The record of one simulated run.

    Attributes:
        seed: the random seed of placements (and adversary choice/inputs).
        times: (T,) s of the recorded frames; positions/velocities (T, N, 2) at those times.
        target_positions: (T, 2) q_r at those times.
        metric_times: (S,) s of every step; metrics[name] (S,) over all agents and
            metrics_non_adversarial[name] over the honest agents only.
        adversaries: (N,) bool.
    """

    seed: int
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    target_positions: np.ndarray
    metric_times: np.ndarray
    metrics: dict
    metrics_non_adversarial: dict
    adversaries: np.ndarray
    scenario: Scenario
    params: FlockingParams

    def com_error(self, non_adversarial: bool = False) -> np.ndarray:
        """‖q̄ − q_r‖ (m) at every step."""
        m = self.metrics_non_adversarial if non_adversarial else self.metrics
        return np.sqrt(m['tracking_mse'])


def initial_state(n_agents: int, rng: np.random.Generator):
    """Positions uniform in [0, 75]² m, velocities zero: (N, 2), (N, 2)."""
    return rng.uniform(0.0, PLACEMENT_BOX, size=(n_agents, 2)), np.zeros((n_agents, 2))


def simulate(scenario: Scenario, params: FlockingParams = FlockingParams(), *, n_agents: int = 50,
             seed: int = 0, duration: float | None = None, dt: float = DT,
             substeps: int = DEFAULT_SUBSTEPS, record_every: int = 1,
             with_metrics: bool = True, progress=None) -> FlockRun:
    """Run one scenario from a random placement (seeded).

    Args:
        scenario: see :func:`make_scenario`.
        params: gains; ``params.gamma_mode`` selects the γ variant.
        n_agents: N.
        seed: seeds placements, the choice of adversaries and their random inputs.
        duration: s (default: the scenario's).
        dt: s, metric/recording step (the report's 0.02 s).
        substeps: control and integration steps per ``dt`` (semi-implicit Euler, h = dt/substeps).
        record_every: keep positions every this many steps (metrics are kept every step).
        with_metrics: compute the per-step metrics (off for benchmarks).
        progress: optional callable(n_steps) called after each step (e.g. tqdm.update).
    """
    if n_agents < 2:
        raise HerdInputError(f'--agents must be at least 2 (got {n_agents})')
    if scenario.n_adversaries >= n_agents:
        raise HerdInputError(f'{scenario.n_adversaries} adversaries leave no honest agent '
                             f'among {n_agents}')
    if dt <= 0 or not math.isfinite(dt):
        raise HerdInputError(f'dt must be > 0 (got {dt})')
    if int(substeps) < 1:
        raise HerdInputError(f'substeps must be >= 1 (got {substeps})')
    substeps = int(substeps)
    h = dt / substeps
    duration = scenario.duration if duration is None else float(duration)
    n_steps = int(round(duration / dt))
    rng = np.random.default_rng(seed)
    q, p = initial_state(n_agents, rng)
    adversaries = np.zeros(n_agents, dtype=bool)
    if scenario.adversary_kind:
        adversaries[rng.choice(n_agents, scenario.n_adversaries, replace=False)] = True
    honest = ~adversaries
    n_adv = int(adversaries.sum())

    n_rec = n_steps // record_every + 1
    rec_q = np.empty((n_rec, n_agents, 2))
    rec_p = np.empty((n_rec, n_agents, 2))
    rec_target = np.empty((n_rec, 2))
    rec_t = np.empty(n_rec)
    metrics = {k: np.empty(n_steps + 1) for k in METRIC_NAMES}
    metrics_honest = {k: np.empty(n_steps + 1) for k in METRIC_NAMES}
    moving = len(scenario.obstacles) and np.any(scenario.obstacles.velocities)

    k_rec = 0
    for step in range(n_steps + 1):
        t = step * dt
        q_r, p_r = scenario.target(t)
        obstacles = scenario.obstacles.at_time(t) if moving else scenario.obstacles
        pairs = neighbour_pairs(q, params.range)
        if step % record_every == 0:
            rec_q[k_rec], rec_p[k_rec], rec_target[k_rec], rec_t[k_rec] = q, p, q_r, t
            k_rec += 1
        if with_metrics:
            for out, members in ((metrics, None), (metrics_honest, honest)):
                values = step_metrics(q, p, q_r, params.distance, params.range, obstacles,
                                      pairs, members)
                for name, v in values.items():
                    out[name][step] = v
        if step == n_steps:
            break
        for sub in range(substeps):
            if sub:
                t_sub = t + sub * h
                q_r, p_r = scenario.target(t_sub)
                obstacles = scenario.obstacles.at_time(t_sub) if moving else scenario.obstacles
                pairs = neighbour_pairs(q, params.range)
            u = flocking_acceleration(q, p, q_r, p_r, params, obstacles, pairs)
            if n_adv:
                if scenario.adversary_kind == 'static':
                    u[adversaries] = 0.0
                    p[adversaries] = 0.0
                else:
                    u[adversaries] = rng.uniform(-RANDOM_INPUT_BOUND, RANDOM_INPUT_BOUND,
                                                 size=(n_adv, 2))
            p = p + u * h
            q = q + p * h
        if progress is not None:
            progress(1)

    if not with_metrics:
        metrics = metrics_honest = {}
    return FlockRun(seed, rec_t[:k_rec], rec_q[:k_rec], rec_p[:k_rec], rec_target[:k_rec],
                    np.arange(n_steps + 1) * dt, metrics, metrics_honest, adversaries,
                    scenario, params)


def settle_time(times, error, threshold: float = 1.0) -> float:
    """First time after which ``error`` stays below ``threshold`` (NaN if it never does)."""
    error = np.asarray(error)
    above = np.flatnonzero(error >= threshold)
    if len(above) == 0:
        return float(times[0])
    if above[-1] == len(error) - 1:
        return float('nan')
    return float(times[above[-1] + 1])


def tracking_summary(run: FlockRun, steady_window: float = 5.0, threshold: float = 1.0,
                     peak_after: float = 5.0) -> dict:
    """Steady CoM error (mean of ‖q̄ − q_r‖ over the last ``steady_window`` s), peak error
    after ``peak_after`` s (the initial gathering excluded), and settle time (m, m, s)."""
    t = run.metric_times
    err = run.com_error(non_adversarial=bool(run.adversaries.any()))
    steady = float(np.mean(err[t >= t[-1] - steady_window]))
    late = t >= peak_after
    peak = float(np.max(err[late])) if np.any(late) else float('nan')
    return {'steady_com_error': steady, 'peak_com_error': peak,
            'settle_time': settle_time(t, err, threshold)}
