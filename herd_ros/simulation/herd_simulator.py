"""Forward simulation of a learned (or true) herd model, eq. 2 with noise w_i ~ N(0, Q_i)
(or the model's stop-and-go noise regimes, :mod:`herd_ros.model.noise_regimes`).

    u^{τ+1} = a ⊙ u^τ + Σ_j f_ij(p^τ) + g_i(p^τ) + w^τ,     p^{τ+1} = p^τ + Δt u^τ

All agents advance together (arrays of shape (N, 2)); one Python step per time step. Many
free runs of one law (noise seeds, starts) advance together too (:func:`simulate_batch`,
arrays (B, N, 2)): the law's cost per Python step barely grows with B.
"""
from __future__ import annotations

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.model.herd_model import HerdModel
from herd_ros.model.noise_regimes import GaussianNoise, noise_for
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


#: positions a batch holds at once (members × steps × agents): chunks of members keep a
#: batch's memory near 100 MB
BATCH_POSITIONS = 6_000_000
#: steps of Gaussian noise drawn at once per member
NOISE_BLOCK = 512


def simulate_batch(model: HerdModel, steps: int, initial_positions: np.ndarray,
                   initial_velocities: np.ndarray, seeds) -> np.ndarray:
    """Free runs of ``model`` from B starts at once: the runs of :func:`simulate` with
    ``seed=seeds[b]`` from ``initial_positions[b]``, ``initial_velocities[b]`` (B, N, 2)
    each, stacked (B, steps, N, 2). The law is evaluated on all members at every step
    (one Python step for B runs: a calibration's or a fidelity check's many runs cost little
    more than one); each member keeps its own generator, so its run is the same as alone
    (to the last bit; with a velocity alignment term, whose sums over members run in
    another order, to rounding).
    Members are simulated in chunks of at most :data:`BATCH_POSITIONS` positions."""
    if steps < 1:
        raise HerdInputError(f'steps must be ≥ 1, got {steps}')
    n = model.n_agents
    p0 = np.array(initial_positions, dtype=float).reshape(-1, n, 2)
    u0 = np.array(initial_velocities, dtype=float).reshape(-1, n, 2)
    seeds = list(seeds)
    if not (len(seeds) == len(p0) == len(u0)):
        raise HerdInputError(f'a batch needs one seed and start per member: {len(seeds)} '
                             f'seeds, {len(p0)} positions, {len(u0)} velocities')
    out = np.empty((len(p0), steps, n, 2))
    chunk = max(1, BATCH_POSITIONS // (steps * n))
    for b0 in range(0, len(p0), chunk):
        sl = slice(b0, b0 + chunk)
        out[sl] = _simulate_members(model, steps, p0[sl], u0[sl], seeds[sl])
    return out


def _simulate_members(model, steps, p, u, seeds):
    """:func:`simulate_batch` of one chunk of members (B, steps, N, 2)."""
    sources = [noise_for(model, seed) for seed in seeds]
    blocks = all(isinstance(s, GaussianNoise) for s in sources)
    out = np.empty((len(p), steps) + p.shape[1:])
    out[:, 0] = p
    kappa = getattr(model, 'velocity_memory', 1.0)
    mean_u = u
    drawn, k = None, NOISE_BLOCK
    for tau in range(1, steps):
        if blocks:
            if k == NOISE_BLOCK:    # the next NOISE_BLOCK steps' noise of every member
                size = min(NOISE_BLOCK, steps - tau)
                drawn = np.stack([s.draw_steps(size) for s in sources], axis=1)
                k = 0
            w = drawn[k]
            k += 1
        else:
            w = np.stack([s.draw() for s in sources])
        u_next = model.next_velocity(mean_u, p, compiled=True) + w
        p = p + model.dt * u
        u = u_next
        mean_u = remember(kappa, mean_u, u)
        out[:, tau] = p
    return out


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
    k0, p0, u0 = run_start(run, model.dt)
    steps = run.n_steps - k0 if steps is None else steps
    return simulate(model, steps, p0, u0, seed=seed, noise=noise, t0=float(run.times[k0]))


def run_start(run: HerdTrajectory, dt: float) -> tuple[int, np.ndarray, np.ndarray]:
    """(k0, p^0, u^0) where :func:`simulate_from` starts a free run of ``run``."""
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
    return k0, p0, (p1 - p0) / dt


def simulate_from_each(model: HerdModel, runs: list, seeds) -> list:
    """:func:`simulate_from` of ``runs[b]`` with ``seeds[b]`` for every b: the same runs,
    simulated together (:func:`simulate_batch`; runs of similar length share a batch)."""
    seeds = list(seeds)
    if len(seeds) != len(runs):
        raise HerdInputError(f'{len(runs)} runs need as many seeds, got {len(seeds)}')
    starts = [run_start(r, model.dt) for r in runs]
    lengths = [r.n_steps - k0 for r, (k0, _, _) in zip(runs, starts)]
    sims = [None] * len(runs)
    order = sorted(range(len(runs)), key=lambda b: -lengths[b])
    while order:                            # the longest left sets its batch's length
        steps = lengths[order[0]]
        batch = order[:max(1, BATCH_POSITIONS // (steps * model.n_agents))]
        order = order[len(batch):]
        out = simulate_batch(model, steps, np.stack([starts[b][1] for b in batch]),
                             np.stack([starts[b][2] for b in batch]),
                             [seeds[b] for b in batch])
        for b, positions in zip(batch, out):
            k0, m = starts[b][0], lengths[b]
            sims[b] = HerdTrajectory(float(runs[b].times[k0]) + model.dt * np.arange(m),
                                     list(model.agents), positions[:m])
    return sims
