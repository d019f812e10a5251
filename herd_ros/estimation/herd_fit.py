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
#: the default training fraction of ``herd-ros fit`` (the first 80 % of every run)
TRAIN_FRACTION = 0.8
#: the fewest held-out steps of a run, and positions of an agent, that count as held out
MIN_HELD_OUT = 3


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
            where = f'run {r.run!r}' if r.run is not None else 'the data fitted'
            raise HerdInputError(f'{where}: agent(s) {", ".join(gone)} have no position at all '
                                 f'(a collar whose fixes all fall in the held-out part: see '
                                 f'--train-fraction, or leave it out of the file)')
    return agents, dt


def aligned_positions(run: HerdTrajectory, agents: list[str]) -> np.ndarray:
    """Positions of ``run`` with columns in ``agents`` order."""
    if list(run.agents) == list(agents):
        return run.positions
    idx = [run.agents.index(a) for a in agents]
    return run.positions[:, idx]


def split_runs(runs: list[HerdTrajectory], train_fraction: float):
    """Time split: the first ``train_fraction`` of every run trains, the rest is held out
    (a run whose rest is shorter than :data:`MIN_HELD_OUT` steps holds out nothing)."""
    if not 0 < train_fraction <= 1:
        raise HerdInputError(f'train fraction must be in (0, 1], got {train_fraction}')
    train, test = [], []
    for r in runs:
        k = int(round(train_fraction * r.n_steps))
        train.append(r.slice(0, k))
        if r.n_steps - k >= MIN_HELD_OUT:
            test.append(r.slice(k, r.n_steps))
    return train, test


def held_out_positions(runs: list[HerdTrajectory], train_fraction: float) -> np.ndarray:
    """Per agent (``runs[0]``'s order), how many positions it has in the part
    :func:`split_runs` holds out at ``train_fraction``."""
    agents = list(runs[0].agents)
    count = np.zeros(len(agents), np.int64)
    for r in runs:
        k = int(round(train_fraction * r.n_steps))
        if r.n_steps - k >= MIN_HELD_OUT:
            count += np.isfinite(aligned_positions(r, agents)[k:]).all(-1).sum(axis=0)
    return count


def fraction_holding_out_each(runs: list[HerdTrajectory],
                              share: float = 1.0 - TRAIN_FRACTION) -> float | None:
    """The largest training fraction, in hundredths and at most :data:`TRAIN_FRACTION`, at
    which every agent holds out at least ``share`` of its own positions (and at least
    :data:`MIN_HELD_OUT`); None if no fraction does (an agent seen only at the start)."""
    agents = list(runs[0].agents)
    total = sum(np.isfinite(aligned_positions(r, agents)).all(-1).sum(axis=0) for r in runs)
    for hundredths in range(int(round(100 * TRAIN_FRACTION)), 0, -1):
        f = hundredths / 100.0
        held = held_out_positions(runs, f)
        if ((held >= share * total) & (held >= MIN_HELD_OUT)).all():
            return f
    return None


def choose_train_fraction(runs: list[HerdTrajectory], requested='auto'
                          ) -> tuple[float, str | None]:
    """The training fraction of ``herd-ros fit`` and a note for the user (or None).

    ``requested`` ``'auto'``: :data:`TRAIN_FRACTION`, unless an agent would then have no
    held-out data (fewer than :data:`MIN_HELD_OUT` positions: its collar ended, or stopped,
    before the split; its one-step skill and its place in the herd's free run could not be
    measured), then :func:`fraction_holding_out_each`: the split where every agent holds
    out the default's share of its own positions. A number is used as given; the note then
    names the agents it leaves without held-out data and the fraction that would not."""
    agents = list(runs[0].agents)
    auto = isinstance(requested, str) and requested.strip().lower() == 'auto'
    if auto:
        fraction = TRAIN_FRACTION
    else:
        try:
            fraction = float(requested)
        except (TypeError, ValueError):
            raise HerdInputError(f'train fraction must be auto or a number in (0, 1], got '
                                 f'{requested!r}') from None
        if not 0 < fraction <= 1:
            raise HerdInputError(f'train fraction must be in (0, 1], got {requested}')
    if fraction == 1.0:
        return fraction, None                     # nothing held out, as asked
    missing = [a for a, c in zip(agents, held_out_positions(runs, fraction))
               if c < MIN_HELD_OUT]
    if not missing:
        return fraction, None
    better = fraction_holding_out_each(runs)
    names = ', '.join(missing)
    share = f'{100 * (1 - TRAIN_FRACTION):.0f} %'
    if auto and better is not None:
        return better, (f'train fraction {better:g} instead of {fraction:g}: at {fraction:g} '
                        f'{names} would have no held-out data (their positions end before '
                        f'the split); at {better:g} every animal holds out at least {share} '
                        f'of its own positions')
    hint = (f'; --train-fraction {better:g} holds out at least {share} of each animal\'s '
            f'positions' if better is not None else '')
    return fraction, (f'at train fraction {fraction:g}, {names} have no held-out data: their '
                      f'one-step skill and their place in the free run are not measured'
                      f'{hint}')


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


def _null_basis(bounds) -> RbfBasis:
    """One centre in the middle of ``bounds``, as wide as they are: the field of a model
    without one (its weights are zero)."""
    xmin, xmax, ymin, ymax = bounds
    return RbfBasis(np.array([[0.5 * (xmin + xmax), 0.5 * (ymin + ymax)]]),
                    np.array([max(xmax - xmin, ymax - ymin, 1.0)]))


def fit_structure(runs: list[HerdTrajectory], structure, law: str = 'pairwise',
                  profile=None, bounds=None, min_visits: int = DEFAULT_MIN_VISITS,
                  se: str = 'sandwich', frame_id: str = 'map', datum=None, progress=None,
                  robust: bool = False, own_agents=(), own_profile=None):
    """Batch least squares (``robust``: the outlier-robust IRLS of
    :mod:`herd_ros.estimation.robust`) of a selected structure (:mod:`model_selection`): the damping
    always, the interactions (pairwise law, or the shared profile when ``law='shared'``)
    and the field on ``structure.grid`` over ``bounds`` only if selected, ridge
    ``structure.ridge``, velocity memory ``structure.memory`` (:mod:`velocity_memory`).
    Terms left out are zero in the model (and in its ``theta_se``).
    ``own_agents`` with ``own_profile``: distinguished agents of the shared law (their own
    profile; see :mod:`herd_ros.model.shared_law`).

    Returns a :class:`HerdFit` whose model is a :class:`HerdModel` (pairwise, or no
    interactions) or a :class:`~herd_ros.model.shared_law.SharedLawModel`."""
    from herd_ros.estimation.model_selection import check_own_agents, structured_regression
    from herd_ros.estimation.robust import fit_agent_robust
    from herd_ros.simulation.prediction import calibrate_prediction_scale
    from herd_ros.model.alignment import VelocityAlignment
    from herd_ros.model.shared_law import SharedLawModel

    agents, dt = check_runs(runs)
    positions = [aligned_positions(r, agents) for r in runs]
    n = len(agents)
    if bounds is None:
        pts = np.concatenate([p.reshape(-1, 2) for p in positions])
        bounds = FieldGrid.over(pts[np.isfinite(pts).all(-1)], 1, 1).bounds
    field_grid = (FieldGrid(structure.grid[0], structure.grid[1], tuple(bounds))
                  if structure.grid is not None else None)
    shared = structure.interactions and law == 'shared'
    if not own_agents and getattr(structure, 'own', ()):
        own_agents, own_profile = structure.own, structure.own_profile
    own = check_own_agents(list(own_agents), agents) if shared else []
    if own and own_profile is None:
        raise HerdInputError('own-profile agents need their profile basis (own_profile)')
    laws, fits, bases, out = {}, {}, [], []
    n_align = structure.alignment.size if getattr(structure, 'alignment', None) else 0
    align_w, align_se, align_cov = [], [], []
    for i, a in enumerate(agents):
        if field_grid is not None:
            visited = np.concatenate([p[:-2, i, :] for p in positions if p.shape[0] >= 3])
            basis = RbfBasis.from_grid(field_grid, visited[np.isfinite(visited).all(-1)],
                                       min_visits)
        else:
            basis = RbfBasis(np.zeros((0, 2)), np.zeros(0))
        reg = structured_regression(positions, i, agents, dt, structure, law, profile, basis,
                                    own, own_profile)
        if robust:
            fit, _ = fit_agent_robust(reg, ridge=structure.ridge, se=se)
        else:
            fit = fit_agent(reg, ridge=structure.ridge, se=se)
        pa, K = reg.A_x.shape[1], basis.size
        th, sd = fit.theta, fit.theta_se
        if i in own:
            # the agent's block with itself was not fitted: zeros in θ and its SE
            at = 1 + profile.size + own.index(i) * own_profile.size
            th = np.insert(th, at, np.zeros(own_profile.size))
            sd = np.insert(sd, at, np.zeros(own_profile.size))
            pa += own_profile.size
        if n_align:
            # the alignment weights (the last columns before the field) into their own term
            align_w.append(th[pa - n_align:pa])
            align_se.append(sd[pa - n_align:pa])
            at = pa - n_align - (own_profile.size if i in own else 0)   # in the fit's θ
            align_cov.append(fit.theta_cov[at:at + n_align, at:at + n_align])
            th = np.delete(th, np.s_[pa - n_align:pa])
            sd = np.delete(sd, np.s_[pa - n_align:pa])
            pa -= n_align
        if K == 0:
            # no field: one centre with zero weight (a ROS parameter array cannot be empty)
            basis, K = _null_basis(bounds), 1
            th, sd = np.concatenate([th, [0.0, 0.0]]), np.concatenate([sd, [0.0, 0.0]])
        fits[a] = fit
        bases.append(basis)
        out.append((th, sd, pa, K))
        if not shared:
            t1, t2, s1, s2 = (np.zeros(n - 1),) * 4
            if structure.interactions:
                t1, t2 = th[1:n], th[n:2 * n - 1]
                s1, s2 = sd[1:n], sd[n:2 * n - 1]
            laws[a] = AgentLaw(damping=th[0], neighbors=reg.neighbors, theta1=t1, theta2=t2,
                               basis=basis, field_u=th[pa:pa + K], field_v=th[pa + K:],
                               noise_cov=fit.noise_cov,
                               theta_se=np.concatenate([[sd[0]], s1, s2, sd[pa:]]))
        if progress is not None:
            progress(a)
    meta = {'min_visits': min_visits, 'ridge': structure.ridge, 'se': se,
            'terms': structure.terms, 'loss': 'robust' if robust else 'l2'}
    if shared:
        B = profile.size
        model = SharedLawModel(
            agents=agents, dt=dt, profile=profile,
            damping=[o[0][0] for o in out], profile_coef=[o[0][1:1 + B] for o in out],
            own_agents=[agents[k] for k in own], own_profile=own_profile if own else None,
            own_coef=[o[0][1 + B:o[2]] for o in out] if own else None,
            bases=bases, field_u=[o[0][o[2]:o[2] + o[3]] for o in out],
            field_v=[o[0][o[2] + o[3]:] for o in out],
            noise_cov=[fits[a].noise_cov for a in agents],
            theta_se=[o[1] for o in out], frame_id=frame_id, datum=datum)
    else:
        model = HerdModel(agents=agents, dt=dt, laws=laws, frame_id=frame_id, datum=datum)
    if n_align:
        model.alignment = VelocityAlignment(structure.alignment, np.array(align_w),
                                            np.array(align_se), np.array(align_cov))
    memory = np.atleast_1d(np.asarray(getattr(structure, 'memory', 1.0), dtype=float))
    if (memory != 1.0).any():
        model.meta['velocity_memory'] = float(memory[0]) if len(memory) == 1 else memory
    model.meta['prediction_scale'] = calibrate_prediction_scale(model, positions)
    return HerdFit(model=model, fits=fits,
                   grid=field_grid if field_grid is not None else FieldGrid(1, 1, tuple(bounds)),
                   meta=meta)

