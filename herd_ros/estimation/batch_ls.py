"""Batch least squares of one agent's θ_i:  θ* = argmin ‖Φθ − Y‖² (+ ridge), by QR.

The design Φ (2m × p) of :mod:`herd_ros.model.regressors` has the structure

    Φ = [ A_x  F  0 ]      θ = [θ_A, θu, θv],   θ_A = [a, θ1·, θ2·]
        [ A_y  0  F ]

so its R factor is computed block-wise (never forming Φ, never an explicit inverse):

1. F = Q_F R_F (thin Householder QR, LAPACK via numpy);
2. project A_x, A_y, y_x, y_y off span(F) (Frisch–Waugh–Lovell);
3. [A_x'; A_y'] = Q_A R_A;
4. R = [[R_A, …], …] assembled in the order (θu, θv, θ_A), z = Qᵀ Y likewise,

which costs O(m K²) instead of the O(m (2K)²) of a dense QR, and gives the same R (up to
row signs) as ``numpy.linalg.qr(Φ)``. θ then solves the small triangular system R θ = z.

Ridge (optional, ``ridge = λ ≥ 0``, dimensionless): minimises ‖Φθ − Y‖² + λ Σ_j ‖Φ_j‖² θ_j²,
i.e. a penalty on each coefficient scaled by the squared norm of its column — the same as a
ridge of λ on standardized columns, so λ means the same whatever the units of a column.
It is solved exactly as the small problem ‖[R; √λ D] θ − [z; 0]‖ (D = diag ‖Φ_j‖).

Standard errors: ``se='sandwich'`` (default) uses the heteroscedasticity-robust sandwich with
the x and y rows of each step as one cluster,

    Cov θ = B (Σ_τ g_τ g_τᵀ) B,   g_τ = Φ_τᵀ r_τ,  B = (ΦᵀΦ + λD²)⁻¹,

valid when the noise of the two components has any covariance Q_i and when Q_i changes
with the state; ``se='ols'`` gives the textbook σ̂² B. Both are computed from R by
triangular solves.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

from herd_ros.errors import HerdInputError
from herd_ros.model.regressors import AgentRegression

#: A column whose R diagonal falls below this fraction of its norm is not identifiable.
RANK_TOLERANCE = 1e-10


@dataclass
class LeastSquaresFit:
    """The result for one agent, θ in DESIGN.md order [a, θ1.., θ2.., θu.., θv..]."""

    theta: np.ndarray
    theta_se: np.ndarray
    theta_cov: np.ndarray
    residuals: np.ndarray  # (m, 2) w^τ
    noise_cov: np.ndarray  # (2, 2) Q_i
    n_samples: int
    condition: float

    @property
    def rms(self) -> float:
        return float(np.sqrt((self.residuals ** 2).sum(-1).mean()))


def triangular_factor(reg: AgentRegression):
    """R (p × p, internal order θu, θv, θ_A) and z = Qᵀ Y of the structured design."""
    F, A_x, A_y = reg.F, reg.A_x, reg.A_y
    m, K = F.shape
    pa = A_x.shape[1]
    if 2 * m < pa + 2 * K:
        raise HerdInputError(f'agent {reg.agent}: {2 * m} equations for {pa + 2 * K} '
                             f'parameters — fewer samples than parameters (record longer, '
                             f'or use a coarser --grid)')
    Q_F, R_F = np.linalg.qr(F, mode='reduced')
    B_x = Q_F.T @ A_x
    B_y = Q_F.T @ A_y
    z_x = Q_F.T @ reg.y_x
    z_y = Q_F.T @ reg.y_y
    A_res = np.vstack([A_x - Q_F @ B_x, A_y - Q_F @ B_y])
    y_res = np.concatenate([reg.y_x - Q_F @ z_x, reg.y_y - Q_F @ z_y])
    Q_A, R_A = np.linalg.qr(A_res, mode='reduced')
    z_A = Q_A.T @ y_res
    p = 2 * K + pa
    R = np.zeros((p, p))
    R[:K, :K] = R_F
    R[K:2 * K, K:2 * K] = R_F
    R[:K, 2 * K:] = B_x
    R[K:2 * K, 2 * K:] = B_y
    R[2 * K:, 2 * K:] = R_A
    return R, np.concatenate([z_x, z_y, z_A])


def _internal_to_theta_order(K: int, pa: int) -> np.ndarray:
    """Index map: theta_order[k] = internal index of θ entry k."""
    return np.concatenate([np.arange(2 * K, 2 * K + pa), np.arange(0, 2 * K)])


def _parameter_label(reg: AgentRegression, internal_index: int) -> str:
    K = reg.F.shape[1]
    names = ([f'field_u[{k}]' for k in range(K)] + [f'field_v[{k}]' for k in range(K)]
             + ['damping'] + [f'theta1[{j}]' for j in reg.neighbors]
             + [f'theta2[{j}]' for j in reg.neighbors])
    return names[internal_index]


def fit_agent(reg: AgentRegression, ridge: float = 0.0, se: str = 'sandwich') -> LeastSquaresFit:
    """Batch least squares of one agent (see the module docstring for the method)."""
    if ridge < 0 or not np.isfinite(ridge):
        raise HerdInputError(f'ridge must be a finite number ≥ 0, got {ridge}')
    m, K = reg.F.shape
    pa = reg.A_x.shape[1]
    R, z = triangular_factor(reg)
    col_norm = np.sqrt((R ** 2).sum(0))  # ‖Φ_j‖: column norms are invariant under Q
    diag = np.abs(np.diag(R))
    weak = diag <= RANK_TOLERANCE * np.maximum(col_norm, 1e-300)
    if ridge == 0 and weak.any():
        bad = _parameter_label(reg, int(np.argmax(weak)))
        raise HerdInputError(f'agent {reg.agent}: singular data — {bad} is not identifiable '
                             f'from these samples (the agent never moves, or a regressor '
                             f'repeats another); add --ridge or more varied data')
    if ridge > 0:
        Ra = np.vstack([R, np.diag(np.sqrt(ridge) * col_norm)])
        za = np.concatenate([z, np.zeros(len(z))])
        Q2, R = np.linalg.qr(Ra, mode='reduced')
        z = Q2.T @ za
    theta_int = solve_triangular(R, z)
    if not np.isfinite(theta_int).all():
        raise HerdInputError(f'agent {reg.agent}: the least-squares solution is not finite '
                             f'(singular data); add --ridge')
    order = _internal_to_theta_order(K, pa)
    theta = theta_int[order]
    # residuals w^τ
    th_a, th_u, th_v = theta[:pa], theta[pa:pa + K], theta[pa + K:]
    r_x = reg.y_x - reg.A_x @ th_a - reg.F @ th_u
    r_y = reg.y_y - reg.A_y @ th_a - reg.F @ th_v
    residuals = np.column_stack([r_x, r_y])
    noise_cov = np.cov(residuals.T, ddof=0) if m > 1 else np.zeros((2, 2))
    # covariance of θ from R by triangular solves
    Rinv = solve_triangular(R, np.eye(len(R)))
    bread = Rinv @ Rinv.T
    if se == 'ols':
        dof = max(2 * m - len(theta), 1)
        cov_int = bread * float((residuals ** 2).sum() / dof)
    elif se == 'sandwich':
        G = np.hstack([reg.F * r_x[:, None], reg.F * r_y[:, None],
                       reg.A_x * r_x[:, None] + reg.A_y * r_y[:, None]])
        meat = G.T @ G
        cov_int = bread @ meat @ bread * (m / max(m - len(theta) / 2.0, 1.0))
    else:
        raise HerdInputError(f'unknown standard-error method {se!r} (sandwich or ols)')
    cov = cov_int[np.ix_(order, order)]
    s = np.linalg.svd(R, compute_uv=False)
    return LeastSquaresFit(theta=theta, theta_se=np.sqrt(np.clip(np.diag(cov), 0, None)),
                           theta_cov=cov, residuals=residuals, noise_cov=noise_cov,
                           n_samples=m, condition=float(s[0] / s[-1]) if s[-1] > 0 else np.inf)
