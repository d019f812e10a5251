"""Regressors of the herd model: eq. 2 written as linear least squares in θ_i (eqs. 6–8).

For agent i and a run of positions p (T, N, 2) on step Δt, with u^τ = (p^{τ+1} − p^τ)/Δt,
every τ = 0 … T−3 gives two rows (x and y) of

    u_i^{τ+1} = Φ_i^τ θ_i + w_i^τ,     θ_i = [a_i, θ1_i·, θ2_i·, θu_i·, θv_i·]

    Φ_i^τ = [ u_x   e_x,ij…   −e_x,ij/d_ij…   φ_k(p_i)…   0…        ]   (x row)
            [ u_y   e_y,ij…   −e_y,ij/d_ij…   0…          φ_k(p_i)… ]   (y row)

with e_ij = (p_j − p_i)/d_ij, d_ij = ‖p_j − p_i‖ at step τ. The field block is the same
matrix F (m × K) in the x and y rows, which the batch solver exploits.

The x and y rows are returned separately: ``A_x, A_y`` (m × (1 + 2(N−1))) hold the damping
and interaction columns, ``F`` (m × K) the basis, ``y_x, y_y`` (m,) the targets.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.model.rbf_field import RbfBasis


@dataclass
class AgentRegression:
    """The stacked regression of one agent over one or more runs."""

    agent: str
    neighbors: list[str]
    A_x: np.ndarray
    A_y: np.ndarray
    F: np.ndarray
    y_x: np.ndarray
    y_y: np.ndarray

    @property
    def n_samples(self) -> int:
        """Number of samples (rows per axis)."""
        return len(self.y_x)

    @property
    def n_params(self) -> int:
        """Number of parameters of θ_i."""
        return self.A_x.shape[1] + 2 * self.F.shape[1]

    def design(self) -> tuple[np.ndarray, np.ndarray]:
        """The dense Φ (2m × p, rows x then y) and Y (2m,) — for tests and small problems."""
        m, k = self.F.shape
        zeros = np.zeros((m, k))
        phi = np.vstack([np.hstack([self.A_x, self.F, zeros]),
                         np.hstack([self.A_y, zeros, self.F])])
        return phi, np.concatenate([self.y_x, self.y_y])


def velocities(positions: np.ndarray, dt: float) -> np.ndarray:
    """u^τ = (p^{τ+1} − p^τ)/Δt: (T, N, 2) -> (T−1, N, 2)."""
    return np.diff(np.asarray(positions, dtype=float), axis=0) / dt


@functools.lru_cache(maxsize=64)
def _others(n: int) -> np.ndarray:
    """(N, N−1): row i lists the other agents in order."""
    return np.array([[j for j in range(n) if j != i] for i in range(n)], dtype=int)


def pairwise_columns(positions: np.ndarray, rows) -> tuple:
    """The pairwise law's interaction columns — the one builder of them, for the batch fit
    and the selection (one agent over many steps) and the RLS (every agent at one step).

    Args:
        positions: (M, N, 2), NaN = missing.
        rows: the agents i (indices) whose columns are wanted.
    Returns:
        (e, e_over_d, coincident): e_ij = (p_j − p_i)/d_ij and e_ij/d_ij, (M, R, N−1, 2) in
        the order of the other agents (a missing neighbour: zero columns, it drops out of
        the sum), and (M, R) where agent i shares its position with a neighbour (d = 0:
        f_ij is undefined).
    """
    p = np.asarray(positions, dtype=float)
    rows = np.atleast_1d(np.asarray(rows, dtype=int))
    off = p[:, _others(p.shape[1])[rows]] - p[:, rows, None]     # (M, R, N−1, 2)
    d = np.sqrt((off ** 2).sum(-1))
    gone = ~np.isfinite(d)
    coincident = (d <= 0).any(-1)
    with np.errstate(invalid='ignore', divide='ignore'):
        e = off / d[..., None]
        e_over_d = e / d[..., None]
    e[gone] = 0.0
    e_over_d[gone] = 0.0
    return e, e_over_d, coincident


def interaction_columns(positions: np.ndarray, i: int, times=None, agents=None):
    """Unit vectors e_ij and e_ij/d_ij from agent i to every other agent
    (:func:`pairwise_columns` of agent i).

    Args:
        positions: (M, N, 2).
        i: the agent.
    Returns:
        e (M, N−1, 2), e/d (M, N−1, 2), in the order of the other agents.
    Raises:
        HerdInputError if two agents coincide (d = 0: f_ij is undefined).

    A neighbour missing at a step (NaN position) drops out: its columns are zero there.
    """
    e, e_over_d, coincident = pairwise_columns(positions, [i])
    if coincident.any():
        p = np.asarray(positions, dtype=float)
        others = [j for j in range(p.shape[1]) if j != i]
        tau = int(np.argmax(coincident[:, 0]))
        k = int(np.argmax(np.sqrt(((p[tau, others] - p[tau, i]) ** 2).sum(-1)) <= 0))
        who = (f'{agents[i]} and {agents[others[k]]}' if agents is not None
               else f'agents {i} and {others[k]}')
        when = f'time {times[tau]:g}' if times is not None else f'step {tau}'
        raise HerdInputError(f'{who} are at the same position at {when}: the interaction '
                             f'f_ij needs a non-zero distance (check for duplicated collars)')
    return e[:, 0], e_over_d[:, 0]


def agent_regression(runs, i: int, basis: RbfBasis, dt: float, agents: list[str],
                     run_times=None) -> AgentRegression:
    """Stack the regression of agent ``i`` over ``runs`` (a list of (T, N, 2) arrays)."""
    ax, ay, fs, yx, yy = [], [], [], [], []
    for r, p in enumerate(runs):
        p = np.asarray(p, dtype=float)
        if p.shape[0] < 3:
            continue
        u = velocities(p, dt)
        pt = p[:-2]  # p^τ for τ = 0..T-3
        times = run_times[r][:-2] if run_times is not None else None
        # a sample needs agent i at τ, τ+1 and τ+2 (missing steps are skipped)
        ok = np.isfinite(p[:-2, i]).all(-1) & np.isfinite(p[1:-1, i]).all(-1) \
            & np.isfinite(p[2:, i]).all(-1)
        if not ok.any():
            continue
        e, e_over_d = interaction_columns(pt[ok], i, None if times is None else times[ok],
                                          agents)
        ax.append(np.column_stack([u[:-1][ok, i, 0], e[..., 0], -e_over_d[..., 0]]))
        ay.append(np.column_stack([u[:-1][ok, i, 1], e[..., 1], -e_over_d[..., 1]]))
        fs.append(basis.features(pt[ok, i, :]))
        yx.append(u[1:][ok, i, 0])
        yy.append(u[1:][ok, i, 1])
    if not ax:
        raise HerdInputError('no run has the three steps one regression sample needs')
    neighbors = [agents[j] for j in range(len(agents)) if j != i]
    return AgentRegression(agents[i], neighbors, np.vstack(ax), np.vstack(ay), np.vstack(fs),
                           np.concatenate(yx), np.concatenate(yy))
