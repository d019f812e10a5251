"""Stop-and-go noise learned online: the online estimator's residual window and its
regime refits (issue 30: pace and its variation in the live graph).

The offline fit gives the law's noise w_i Markov-switching regimes
(:mod:`herd_ros.model.noise_regimes`: a hidden Markov chain z_i with w_i | z_i = k ~ N(0,
Q_ik), fitted by Baum–Welch, K chosen by BIC). Online, the recursive least squares gives
each update's a-priori residual e_i^τ = y_i^τ − H_i^τ θ_i^{τ−1}, the one-step residual of
eq. 2 under the estimate before the update; standardized, ε = L⁻¹ e with L Lᵀ = I + H P Hᵀ,
its covariance is Q_i however uncertain θ still is (the residual sum the RLS estimates Q_i
from, :meth:`~herd_ros.estimation.rls.HerdRLS.noise_cov`). This module keeps the last
``window`` of them (a gap in the herd clock, or an agent whose update
was skipped, is a missing emission: the chain runs on through it) and refits the regimes
on that window when asked, so a robot driven by the live law rests and moves in bursts as
its animal does instead of drifting at a steady Gaussian pace (a Gaussian velocity has
std/mean of speed 0.52; a baboon's at 5 s is about 1).

The regimes are published as fitted: their stationary mean is the noise covariance of
the last ``window`` steps, not Q_i of the whole run (with forgetting 1, Q_i averages the
herd's whole history). A herd whose pace changes — a troop that leaves its sleeping site
and travels, cattle that rest at noon — is imitated at its present pace: on the baboons'
hour, whose pace quadruples from the first five minutes to the last twenty, robots with
noise scaled to Q_i fell 34 % behind in mean speed, with the window's own level 6 %.

Plain numpy; no ROS. Used by :class:`~herd_ros.estimation.online_fit.OnlineHerdEstimator`
and the ``estimator`` and ``controller`` nodes.
"""
from __future__ import annotations

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.model.noise_regimes import REGIME_COUNTS, check_regimes, fit_herd_regimes

#: residuals an agent needs in the window before the first regime fit (a two-regime chain
#: has five parameters per agent; 120 steps hold a few rests and moves of a minute or two)
MIN_RESIDUALS = 120
#: a K larger than 1 needs a BIC lower by more than this: "very strong" evidence (Kass &
#: Raftery 1995). A window is short and refitted often; a marginal choice would flip
#: between one and two regimes from one refit to the next (the three synthetic cows: BIC
#: differences of −7 to +9 over an hour), the nineteen baboons' differ by thousands.
BIC_MARGIN = 10.0


class ResidualWindow:
    """The last ``window`` rows of residuals (N, 2) of a herd, oldest first; a row of NaN
    is a missing emission (a gap, or no update)."""

    def __init__(self, n_agents: int, window: int):
        if int(window) < 1:
            raise HerdInputError(f'the residual window must hold at least one step, got '
                                 f'{window}')
        self.rows = np.full((int(window), int(n_agents), 2), np.nan)
        self.head = 0           # where the next row goes
        self.filled = 0

    def push(self, residual=None):
        """Append one step's residuals ((N, 2), NaN where an agent has none), or a missing
        step (None: a gap in the herd clock)."""
        row = self.rows[self.head]
        row[:] = np.nan
        if residual is not None:
            row[:] = np.asarray(residual, dtype=float).reshape(row.shape)
        self.head = (self.head + 1) % len(self.rows)
        self.filled = min(self.filled + 1, len(self.rows))

    def residuals(self) -> np.ndarray:
        """(T, N, 2) in time order, T ≤ window."""
        if self.filled < len(self.rows):
            return self.rows[:self.filled].copy()
        return np.concatenate([self.rows[self.head:], self.rows[:self.head]])

    def counts(self) -> np.ndarray:
        """Residuals held per agent (N,)."""
        return np.isfinite(self.residuals()).all(-1).sum(0)

    def clear(self):
        """Forget every residual (a reset, a new session)."""
        self.rows[:] = np.nan
        self.head = self.filled = 0


def rank_one_factor(outer) -> np.ndarray:
    """r (..., 2) with r rᵀ = ``outer`` (..., 2, 2), a rank-one outer product ε εᵀ: ε up
    to its sign, which a zero-mean Gaussian likelihood does not see."""
    o = np.asarray(outer, dtype=float)
    a = np.sqrt(np.clip(o[..., 0, 0], 0.0, None))
    c = np.sqrt(np.clip(o[..., 1, 1], 0.0, None))
    return np.stack([a, np.where(o[..., 0, 1] < 0, -c, c)], axis=-1)


def fit_residuals(residuals, counts=REGIME_COUNTS, margin: float = BIC_MARGIN):
    """The regimes of residuals (T, N, 2) taken out of a window
    (:meth:`ResidualWindow.residuals`, a copy: a refit in a worker thread works on it; the
    EM kernel releases the GIL): (covariances (N, K, 2, 2), transition (N, K, K), fit
    summary of :func:`~herd_ros.model.noise_regimes.fit_herd_regimes`), or None when there
    are too few residuals for any fit. More regimes than one only on very strong evidence
    (BIC lower by more than ``margin``). An agent with too few residuals for K regimes gets
    K copies of its residuals' covariance (Gaussian noise)."""
    try:
        fit = fit_herd_regimes(residuals, counts, margin)
    except HerdInputError:
        return None
    cov = np.stack([f['covariances'] for f in fit['agents']])
    trans = np.stack([f['transition'] for f in fit['agents']])
    return cov, trans, fit


def pack_regimes(covariances, transition) -> np.ndarray:
    """(N, K, 4 + K): per agent and regime [qxx, qxy, qyx, qyy, Π_k1 … Π_kK], the rows of
    ``/herd/model/noise_regimes`` (doc/formats.md)."""
    cov = np.asarray(covariances, dtype=float)
    trans = np.asarray(transition, dtype=float)
    n, k = cov.shape[:2]
    return np.concatenate([cov.reshape(n, k, 4), trans], axis=2)


def unpack_regimes(rows, n_agents: int, where: str = '/herd/model/noise_regimes'):
    """(covariances (N, K, 2, 2), transition (N, K, K)) from :func:`pack_regimes`' rows
    ((N, K, 4 + K), or flat with K implied); one clear HerdInputError when they do not fit
    ``n_agents`` agents or are not covariances and transition probabilities."""
    a = np.asarray(rows, dtype=float).ravel()
    n = int(n_agents)
    k = 0
    for cand in (1, 2, 3, 4, 5, 6):
        if a.size == n * cand * (4 + cand):
            k = cand
            break
    if not k:
        raise HerdInputError(f'{where}: {a.size} numbers do not make {n} agents × K regimes '
                             f'× (4 + K) values')
    a = a.reshape(n, k, 4 + k)
    cov, trans = np.empty((n, k, 2, 2)), np.empty((n, k, k))
    for i in range(n):
        cov[i], trans[i] = check_regimes(a[i, :, :4], a[i, :, 4:], f'{where}, agent {i}')
    return cov, trans
