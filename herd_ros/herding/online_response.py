"""The herd's mean response to its herders, refitted online while herding (issue 27).

The herder's law (:class:`~herd_ros.herding.model_herder.LearnedResponse`) is linear in
θ = [ā, c_1..c_B, h_1..h_B']::

    u_i^{τ+1} = ā u_i^τ + Σ_j Σ_b c_b ψ_b(d_ij) e_ij + Σ_k Σ_b h_b ψ'_b(d_ik) e_ik + w_i^τ

with u^τ = p^{τ+1} − p^τ, the distances d and unit vectors e (towards the other) at p^τ
(the convention of Schwager et al. 2007, eq. 2, and of :mod:`~herd_ros.model.regressors`),
j over the animals and k over the herders: the columns of
:func:`~herd_ros.model.shared_law.shared_columns` (the herders' blocks summed: every
herder is "the dog"). Each step of an episode gives 2N rows (x, y), one per animal and
axis (:func:`response_rows`).

:class:`OnlineResponse` keeps one recursive least-squares estimate per episode, in
information form (Ljung & Söderström 1983, *Theory and Practice of Recursive
Identification*, §2.2), vectorised over episodes::

    Λ = Λ₀ + Σ x xᵀ,   b = Λ₀ θ₀ + Σ x y,   θ = Λ⁻¹ b

— the posterior mean of θ under the Gaussian prior N(θ₀, Λ₀⁻¹) (the rows' noise variance
common to prior and data). θ₀ is the offline fit; Λ₀ is the offline data's information
per row times ``prior_steps`` · 2N rows: the prior weighs as much as ``prior_steps`` steps
of this herd, so a herd that responds otherwise than the recordings outweighs it within a
few minutes of herding.

Plain numpy; no ROS.
"""
from __future__ import annotations

import numpy as np

from herd_ros.model.shared_law import shared_columns


def response_rows(P, U, dogs, profile, own_profile):
    """The regressors x (S, N, 2, p) of the animals' displacements u^{τ+1}, one step of S
    herds: their displacements ``U`` = u^τ (S, N, 2), and the animals ``P`` (S, N, 2) and
    herders ``dogs`` (S, D, 2) at τ (module docstring)."""
    P = np.asarray(P, dtype=float)
    S, N, _ = P.shape
    D = dogs.shape[1]
    cols, _ = shared_columns(np.concatenate([P, dogs], axis=1), np.arange(N), profile,
                             own=range(N, N + D), own_profile=own_profile)
    B, Bo = profile.size, own_profile.size
    inter = cols[:, :, :B]                                              # (S, N, B, 2)
    dog = cols[:, :, B:].reshape(S, N, D, Bo, 2).sum(axis=2)            # (S, N, B', 2)
    x = np.concatenate([np.asarray(U, dtype=float)[:, :, None, :], inter, dog], axis=2)
    return np.moveaxis(x, 3, 2)                                         # (S, N, 2, p)


def run_information(runs, profile, own_profile, dog: int = -1) -> tuple[np.ndarray, int]:
    """Σ x xᵀ over every step of recorded ``runs`` (:class:`HerdTrajectory` on a 1 s clock,
    the herder at index ``dog``, the animals the others) and the number of rows."""
    p = 1 + profile.size + own_profile.size
    info = np.zeros((p, p))
    rows = 0
    for run in runs:
        pos = np.asarray(run.positions, dtype=float)
        animals = np.delete(np.arange(pos.shape[1]), dog % pos.shape[1])
        herd, herders = pos[:, animals], pos[:, [dog % pos.shape[1]]]
        x = response_rows(herd[:-2], herd[1:-1] - herd[:-2], herders[:-2], profile,
                          own_profile).reshape(-1, p)
        x = x[np.isfinite(x).all(axis=1)]
        info += x.T @ x
        rows += len(x)
    return info, rows


class OnlineResponse:
    """S episodes' estimates of θ by recursive least squares in information form
    (module docstring)."""

    def __init__(self, theta0, info_per_row, n_episodes: int, rows_per_step: int,
                 prior_steps: float = 150.0):
        theta0 = np.asarray(theta0, dtype=float)
        lam0 = np.asarray(info_per_row, dtype=float) * (prior_steps * rows_per_step)
        self.info = np.repeat(lam0[None], n_episodes, axis=0)           # Λ (S, p, p)
        self.vector = np.repeat((lam0 @ theta0)[None], n_episodes, axis=0)   # b (S, p)
        self.theta = np.repeat(theta0[None], n_episodes, axis=0)        # θ (S, p)
        self.rows = np.zeros(n_episodes, np.int64)

    def update(self, episodes, x, y):
        """Add the rows of ``episodes`` (E,): x (E, R, p), y (E, R) (non-finite rows are
        skipped), and re-solve their θ."""
        ok = np.isfinite(x).all(axis=-1) & np.isfinite(y)
        x = np.where(ok[..., None], x, 0.0)
        y = np.where(ok, y, 0.0)
        self.info[episodes] += np.einsum('erp,erq->epq', x, x)
        self.vector[episodes] += np.einsum('erp,er->ep', x, y)
        self.rows[episodes] += ok.sum(axis=1)
        self.theta[episodes] = np.linalg.solve(self.info[episodes],
                                               self.vector[episodes][..., None])[..., 0]
