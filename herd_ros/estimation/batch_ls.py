"""Batch least squares of one agent's θ_i:  θ* = argmin ‖Φθ − Y‖² (+ ridge), by QR.

The design Φ (2m × p) of :mod:`herd_ros.model.regressors` has the structure

    Φ = [ A_x  F  0 ]      θ = [θ_A, θu, θv],   θ_A = [a, θ1·, θ2·]
        [ A_y  0  F ]

so its R factor is computed block-wise (never forming Φ, never an explicit inverse):

1. F = Q_F R_F (Householder QR by row blocks, TSQR, Q never formed);
2. A_x, A_y, y_x, y_y projected off span(F) (Frisch–Waugh–Lovell) come out of the same QR;
3. [A_x'; A_y'] = Q_A R_A from the small trailing factor;
4. R = [[R_F, 0, B_x], [0, R_F, B_y], [0, 0, R_A]] in the order (θu, θv, θ_A), z = Qᵀ Y,

which costs O(m (K + 2 p_A)²) instead of the O(m (2K + p_A)²) of a dense QR of Φ, and gives
the same R (up to row signs) as ``numpy.linalg.qr(Φ)``. θ solves the triangular R θ = z.

Ridge (optional, ``ridge = λ ≥ 0``, dimensionless): minimises ‖Φθ − Y‖² + λ Σ_j ‖Φ_j‖² θ_j²
over every coefficient but the damping a, i.e. a penalty on each field and interaction
coefficient scaled by the squared norm of its column — the same as a ridge of λ on
standardized columns, so λ means the same whatever the units of a column. The damping is
left free (unless its column is degenerate): the data identify it well, and a penalty on it
pulls the model towards "stay put" (λ = 0.1 took ~10 % off every damping of a known-truth
herd). It is solved exactly as the small problem ‖[R; √λ D] θ − [z; 0]‖ (D = diag ‖Φ_j‖,
D_a = 0).

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
#: The largest |damping| a fit returns: u^{τ+1} = a ū^τ + … is stable only for |a| < 1.
#: Data whose unconstrained least squares give |a| ≥ this (an accelerating stretch, a
#: drift) get the damping fixed here and the other terms refitted (issue 30).
DAMPING_MAX = 0.999


@dataclass
class LeastSquaresFit:
    """The result for one agent, θ in doc/formats.md order [a, θ1.., θ2.., θu.., θv..]."""

    theta: np.ndarray
    theta_se: np.ndarray
    theta_cov: np.ndarray
    residuals: np.ndarray  # (m, 2) w^τ
    noise_cov: np.ndarray  # (2, 2) Q_i
    n_samples: int
    condition: float
    constrained: str = ''    # why a parameter was held (the damping at ±DAMPING_MAX), or ''

    @property
    def rms(self) -> float:
        """RMS (m/s) of the residual velocity vectors."""
        return float(np.sqrt((self.residuals ** 2).sum(-1).mean()))


def tall_r(M: np.ndarray, chunk: int = 16384) -> np.ndarray:
    """R factor of a tall matrix by TSQR (Demmel et al. 2012): QR of row blocks, then of
    the stacked block R's. Same R as a one-shot Householder QR (up to row signs), without
    forming Q, and cache-friendly for millions of rows."""
    m, n = M.shape
    if m <= 2 * chunk:
        return np.linalg.qr(M, mode='r')
    blocks = [np.linalg.qr(M[k:k + chunk], mode='r') for k in range(0, m, chunk)]
    return np.linalg.qr(np.vstack(blocks), mode='r')


def triangular_factor(reg: AgentRegression):
    """R (p × p, internal order θu, θv, θ_A) and z = Qᵀ Y of the structured design.

    One TSQR of M = [F, A_x, y_x, A_y, y_y] (m rows) gives, in its first K rows, R_F and
    Q_Fᵀ[A_x, y_x, A_y, y_y]; its trailing block T is the R factor of the same columns
    projected off span(F). The x and y parts of T, stacked, have the R factor of the
    projected vertical stack [[A_x', y_x'], [A_y', y_y']] (both share the orthonormal
    basis of T), which gives R_A and z_A — exactly, without normal equations.
    """
    F, A_x, A_y = reg.F, reg.A_x, reg.A_y
    m, K = F.shape
    pa = A_x.shape[1]
    if 2 * m < pa + 2 * K:
        raise HerdInputError(f'agent {reg.agent}: {2 * m} equations for {pa + 2 * K} '
                             f'parameters — fewer samples than parameters (record longer, '
                             f'or use a coarser --grid)')
    M = np.hstack([F, A_x, reg.y_x[:, None], A_y, reg.y_y[:, None]])
    Rm = tall_r(M)
    n = Rm.shape[1]
    if Rm.shape[0] < n:  # fewer rows than columns: pad (the design is then rank-deficient)
        Rm = np.vstack([Rm, np.zeros((n - Rm.shape[0], n))])
    xs = slice(K, K + pa + 1)
    ys = slice(K + pa + 1, K + 2 * pa + 2)
    R_F = Rm[:K, :K]
    top_x, top_y = Rm[:K, xs], Rm[:K, ys]
    T = Rm[K:, K:]
    W = np.vstack([T[:, :pa + 1], T[:, pa + 1:]])
    RW = np.linalg.qr(W, mode='r')
    if RW.shape[0] < pa + 1:
        RW = np.vstack([RW, np.zeros((pa + 1 - RW.shape[0], pa + 1))])
    p = 2 * K + pa
    R = np.zeros((p, p))
    R[:K, :K] = R_F
    R[K:2 * K, K:2 * K] = R_F
    R[:K, 2 * K:] = top_x[:, :pa]
    R[K:2 * K, 2 * K:] = top_y[:, :pa]
    R[2 * K:, 2 * K:] = RW[:pa, :pa]
    z = np.concatenate([top_x[:, pa], top_y[:, pa], RW[:pa, pa]])
    return R, z


def _internal_to_theta_order(K: int, pa: int) -> np.ndarray:
    """Index map: theta_order[k] = internal index of θ entry k."""
    return np.concatenate([np.arange(2 * K, 2 * K + pa), np.arange(0, 2 * K)])


def _parameter_label(reg: AgentRegression, internal_index: int) -> str:
    K = reg.F.shape[1]
    names = ([f'field_u[{k}]' for k in range(K)] + [f'field_v[{k}]' for k in range(K)]
             + ['damping'] + [f'theta1[{j}]' for j in reg.neighbors]
             + [f'theta2[{j}]' for j in reg.neighbors])
    return names[internal_index]


def fit_agent(reg: AgentRegression, ridge: float = 0.0, se: str = 'sandwich',
              stable: bool = True) -> LeastSquaresFit:
    """Batch least squares of one agent (see the module docstring for the method); with
    ``stable`` (default) a damping at or beyond ±:data:`DAMPING_MAX` is held there and the
    other terms refitted (``constrained`` says so)."""
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
        pen = np.sqrt(ridge) * col_norm
        a = 2 * K                         # the damping's internal index (θ order: first)
        if not weak[a]:
            pen[a] = 0.0                  # the data identify it: never pulled to stay-put
        Ra = np.vstack([R, np.diag(pen)])
        za = np.concatenate([z, np.zeros(len(z))])
        Q2, R = np.linalg.qr(Ra, mode='reduced')
        z = Q2.T @ za
    theta_int = solve_triangular(R, z)
    if not np.isfinite(theta_int).all():
        raise HerdInputError(f'agent {reg.agent}: the least-squares solution is not finite '
                             f'(singular data); add --ridge')
    a = 2 * K                             # the damping's internal index
    free = np.ones(len(theta_int), bool)
    constrained = ''
    if stable and abs(theta_int[a]) >= DAMPING_MAX:
        # min ‖R θ − z‖ with θ_a held at ±DAMPING_MAX: the other columns refitted to
        # z − R_a θ_a (a QR of R without column a: p × (p − 1), cheap)
        held = float(np.copysign(DAMPING_MAX, theta_int[a]))
        constrained = (f'damping {theta_int[a]:.4f} of the unconstrained fit is not stable '
                       f'(|a| ≥ 1 - {1 - DAMPING_MAX:g}): held at {held:g}, the other terms '
                       f'refitted')
        free[a] = False
        Qf, Rf = np.linalg.qr(R[:, free], mode='reduced')
        theta_int = np.empty_like(theta_int)
        theta_int[a] = held
        theta_int[free] = solve_triangular(Rf, Qf.T @ (z - R[:, a] * held))
        R = Rf
    order = _internal_to_theta_order(K, pa)
    theta = theta_int[order]
    # residuals w^τ
    th_a, th_u, th_v = theta[:pa], theta[pa:pa + K], theta[pa + K:]
    r_x = reg.y_x - reg.A_x @ th_a - reg.F @ th_u
    r_y = reg.y_y - reg.A_y @ th_a - reg.F @ th_v
    residuals = np.column_stack([r_x, r_y])
    # Q_i with the degrees of freedom the fit used up: p parameters over 2m equations, so
    # each component loses p/2 (plain rᵀr/m underestimates Q by p/2m, which matters for a
    # short recording and makes simulated herds too calm)
    dof = max(m - len(theta) / 2.0, 1.0)
    noise_cov = residuals.T @ residuals / dof
    # covariance of θ from R by triangular solves (a held parameter: zero variance)
    Rinv = solve_triangular(R, np.eye(len(R)))
    bread = Rinv @ Rinv.T
    if se == 'ols':
        dof = max(2 * m - len(theta), 1)
        cov_free = bread * float((residuals ** 2).sum() / dof)
    elif se == 'sandwich':
        G = np.hstack([reg.F * r_x[:, None], reg.F * r_y[:, None],
                       reg.A_x * r_x[:, None] + reg.A_y * r_y[:, None]])[:, free]
        meat = G.T @ G
        cov_free = bread @ meat @ bread * (m / max(m - len(theta) / 2.0, 1.0))
    else:
        raise HerdInputError(f'unknown standard-error method {se!r} (sandwich or ols)')
    cov_int = np.zeros((len(theta), len(theta)))
    cov_int[np.ix_(free, free)] = cov_free
    cov = cov_int[np.ix_(order, order)]
    s = np.linalg.svd(R, compute_uv=False) if R.shape[1] else np.ones(1)   # all held: 1
    return LeastSquaresFit(theta=theta, theta_se=np.sqrt(np.clip(np.diag(cov), 0, None)),
                           theta_cov=cov, residuals=residuals, noise_cov=noise_cov,
                           n_samples=m, condition=float(s[0] / s[-1]) if s[-1] > 0 else np.inf,
                           constrained=constrained)
