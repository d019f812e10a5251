"""Fit the herd model to trajectories: grid → pruned basis per agent → regressors → batch LS.

This is the offline method of Schwager et al. (2007) end to end; ``herd-ros fit`` and the
tests drive it. Each agent gets its own pruned set of centres (the cells *it* visited at
least ``min_visits`` times) on the common grid, its own θ_i and its own Q_i.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.estimation.batch_ls import LeastSquaresFit, fit_agent
from herd_ros.model.herd_model import AgentLaw, HerdModel
from herd_ros.model.rbf_field import DEFAULT_MIN_VISITS, FieldGrid, RbfBasis
from herd_ros.model.regressors import agent_regression
from herd_ros.trajectory import HerdTrajectory

DEFAULT_GRID = (8, 8)


@dataclass
class HerdFit:
    """A fitted model with the per-agent least-squares results behind it."""

    model: HerdModel
    fits: dict[str, LeastSquaresFit]
    grid: FieldGrid
    meta: dict = field(default_factory=dict)


def check_runs(runs: list[HerdTrajectory]) -> tuple[list[str], float]:
    """All runs must have the same agents and the same Δt; returns (agents, dt)."""
    if not runs:
        raise HerdInputError('no trajectory data')
    agents = list(runs[0].agents)
    if len(agents) < 2:
        raise HerdInputError(f'the herd model needs at least two agents, got {agents}')
    dt = runs[0].dt
    for r in runs:
        if list(r.agents) != agents and sorted(r.agents) != sorted(agents):
            raise HerdInputError(f'run {r.run!r} has agents {r.agents}, run {runs[0].run!r} '
                                 f'has {agents}: every run needs the same herd')
        if abs(r.dt - dt) > 1e-6 * dt:
            raise HerdInputError(f'run {r.run!r} has step {r.dt:g} s, run {runs[0].run!r} '
                                 f'{dt:g} s: every run needs the same clock step')
        present = np.isfinite(r.positions).all(-1)
        if not present.any(axis=0).all():
            gone = [a for a, have in zip(r.agents, present.any(axis=0)) if not have]
            raise HerdInputError(f'run {r.run!r}: agent(s) {", ".join(gone)} have no position '
                                 f'at all')
    return agents, dt


def aligned_positions(run: HerdTrajectory, agents: list[str]) -> np.ndarray:
    """Positions of ``run`` with columns in ``agents`` order."""
    if list(run.agents) == list(agents):
        return run.positions
    idx = [run.agents.index(a) for a in agents]
    return run.positions[:, idx]


def split_runs(runs: list[HerdTrajectory], train_fraction: float):
    """Time split: the first ``train_fraction`` of every run trains, the rest is held out."""
    if not 0 < train_fraction <= 1:
        raise HerdInputError(f'train fraction must be in (0, 1], got {train_fraction}')
    train, test = [], []
    for r in runs:
        k = int(round(train_fraction * r.n_steps))
        train.append(r.slice(0, k))
        if r.n_steps - k >= 3:
            test.append(r.slice(k, r.n_steps))
    return train, test


def fit_herd(runs: list[HerdTrajectory], grid: tuple[int, int] = DEFAULT_GRID,
             bounds: tuple[float, float, float, float] | None = None,
             min_visits: int = DEFAULT_MIN_VISITS, ridge: float = 0.0, se: str = 'sandwich',
             frame_id: str = 'map', datum=None, progress=None) -> HerdFit:
    """Batch least squares of every agent's θ_i on ``runs`` (see :mod:`batch_ls`).

    Args:
        runs: trajectories on one uniform clock (same agents and Δt in every run).
        grid: (nx, ny) RBF grid; ``bounds`` (xmin, xmax, ymin, ymax) default to the
            bounding box of all positions.
        min_visits: samples of an agent that must fall in a cell to keep its centre.
        ridge: dimensionless ridge λ (see :func:`fit_agent`).
        progress: optional callable(agent) called after each agent (progress bars).
    """
    agents, dt = check_runs(runs)
    positions = [aligned_positions(r, agents) for r in runs]
    times = [r.times for r in runs]
    if sum(max(p.shape[0] - 2, 0) for p in positions) < 1:
        raise HerdInputError('fewer than three time steps: nothing to fit')
    if bounds is None:
        pts = np.concatenate([p.reshape(-1, 2) for p in positions])
        field_grid = FieldGrid.over(pts[np.isfinite(pts).all(-1)], grid[0], grid[1])
    else:
        field_grid = FieldGrid(grid[0], grid[1], tuple(float(b) for b in bounds))
    laws, fits = {}, {}
    for i, a in enumerate(agents):
        visited = np.concatenate([p[:-2, i, :] for p in positions if p.shape[0] >= 3])
        visited = visited[np.isfinite(visited).all(-1)]
        basis = RbfBasis.from_grid(field_grid, visited, min_visits)
        if basis.size == 0:
            raise HerdInputError(f'agent {a}: no grid cell has {min_visits} samples; lower '
                                 f'--min-visits, coarsen --grid or check --bounds')
        reg = agent_regression(positions, i, basis, dt, agents, times)
        fit = fit_agent(reg, ridge=ridge, se=se)
        n = len(agents) - 1
        K = basis.size
        th = fit.theta
        laws[a] = AgentLaw(damping=th[0], neighbors=reg.neighbors, theta1=th[1:1 + n],
                           theta2=th[1 + n:1 + 2 * n], basis=basis,
                           field_u=th[1 + 2 * n:1 + 2 * n + K], field_v=th[1 + 2 * n + K:],
                           noise_cov=fit.noise_cov, theta_se=fit.theta_se)
        fits[a] = fit
        if progress is not None:
            progress(a)
    model = HerdModel(agents=agents, dt=dt, laws=laws, frame_id=frame_id, datum=datum)
    return HerdFit(model=model, fits=fits, grid=field_grid,
                   meta={'min_visits': min_visits, 'ridge': ridge, 'se': se})
