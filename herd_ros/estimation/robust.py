"""Outlier-robust estimation of one agent's θ_i: iteratively reweighted least squares.

A real collar's bad spell — a burst of fixes a kilometre off that the ingest let through, a
jump at a re-acquisition — puts into the regression a few steps whose velocity is thousands
of times the animal's: both as the target u^{τ+1} and as the regressor u^τ (a leverage
point). Plain least squares follows them. Every sample τ (its x and y rows together) gets a
weight from the Mahalanobis distance of its residual,

    d_τ² = w_τᵀ Q⁻¹ w_τ,     ω_τ = 1 if d_τ² ≤ c,  c / d_τ² otherwise,     c = χ²₂(0.95),

which inflates the noise covariance of an outlying sample by d²/c — the robust Kalman
update of Chang (2014, "Robust Kalman filtering based on Mahalanobis distance as outlier
judging criterion", *J. Geodesy* 88:391–401), here applied to regression samples. Its
influence on θ, ω x r, stays bounded even for a leverage point (r grows with x), unlike
Huber's ω = √c/d, whose influence grows with x; and ω d² ≤ c bounds what a sample adds to
Q. θ and Q are re-estimated in turn (IRLS, Holland & Welsch 1977) on the structured QR of
:func:`~herd_ros.estimation.batch_ls.fit_agent` with the rows scaled by √ω (the x and y rows
of a step share ω, so the design keeps its structure). The weights only judge residuals,
so the start must not be set by the outliers: the exit step of a burst (regressor u^τ of
1 km/Δt, target a normal velocity) fits a damping of 0 *exactly*, and from a plain
least-squares start IRLS stayed there (measured: damping 0.0001 for a true 0.93). The
start is therefore least squares without the leverage points — samples whose velocity
regressor is beyond χ²₂(0.999) in the robust (median/MAD) distance, as a Mallows
GM-estimator screens them — with Q from the median absolute deviation of its residuals;
after it, every sample takes part with its residual weight (genuinely fast steps are not
lost). Q is Σ ω w wᵀ / Σ ω times 2 / E[min(χ²₂, c)] = 2 / (2(1 − e^{−c/2})),
consistent for Gaussian noise. Standard errors: the sandwich of the weighted problem (the
M-estimator sandwich with ψ(r) = ω r).

The online estimator applies the same weight to each update, from its a-priori innovation
(:mod:`herd_ros.estimation.online_fit`).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from herd_ros.estimation.batch_ls import LeastSquaresFit, fit_agent
from herd_ros.model.regressors import AgentRegression

#: Mahalanobis² beyond which a sample is down-weighted (χ²₂ at 0.95).
OUTLIER_CHI2 = 5.991464547107979
#: Robust distance² of the velocity regressor beyond which the start leaves a sample out.
LEVERAGE_CHI2 = 13.815510557964274
#: E[min(χ²₂, c)] / 2 for the consistency of Q.
_CONSISTENCY = 1.0 - np.exp(-OUTLIER_CHI2 / 2.0)


def outlier_weight(d2, threshold: float = OUTLIER_CHI2) -> np.ndarray:
    """ω = 1 for d² ≤ c, c/d² beyond (module docstring); NaN d² gets 0."""
    d2 = np.asarray(d2, dtype=float)
    with np.errstate(divide='ignore', invalid='ignore'):
        w = np.where(d2 <= threshold, 1.0, threshold / d2)
    return np.where(np.isfinite(w), w, 0.0)


def mahalanobis2(residuals: np.ndarray, q: np.ndarray) -> np.ndarray:
    """d² = rᵀ Q⁻¹ r for residuals (m, 2)."""
    return np.einsum('mi,ij,mj->m', residuals, np.linalg.pinv(q), residuals)


def robust_noise_cov(residuals: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Q from weighted residuals, consistent for Gaussian noise (module docstring)."""
    w = np.asarray(weights, dtype=float)
    q = ((w[:, None, None] * residuals[:, :, None] * residuals[:, None, :]).sum(0)
         / max(w.sum(), 1e-300))
    return q / _CONSISTENCY


def mad_noise_cov(residuals: np.ndarray) -> np.ndarray:
    """A diagonal Q from the median absolute deviation of each residual component."""
    r = residuals - np.median(residuals, axis=0)
    s = 1.4826 * np.median(np.abs(r), axis=0)
    s = np.where(s > 0, s, np.std(residuals, axis=0) + 1e-12)
    return np.diag(s ** 2)


def _residuals(reg: AgentRegression, theta: np.ndarray) -> np.ndarray:
    """Unweighted residuals (m, 2) of θ (DESIGN order) on the regression."""
    pa, K = reg.A_x.shape[1], reg.F.shape[1]
    r_x = reg.y_x - reg.A_x @ theta[:pa] - reg.F @ theta[pa:pa + K]
    r_y = reg.y_y - reg.A_y @ theta[:pa] - reg.F @ theta[pa + K:]
    return np.column_stack([r_x, r_y])


def _weighted(reg: AgentRegression, w: np.ndarray) -> AgentRegression:
    s = np.sqrt(w)
    return replace(reg, A_x=reg.A_x * s[:, None], A_y=reg.A_y * s[:, None],
                   F=reg.F * s[:, None], y_x=reg.y_x * s, y_y=reg.y_y * s)


def fit_agent_robust(reg: AgentRegression, ridge: float = 0.0, se: str = 'sandwich',
                     max_iter: int = 30, tol: float = 1e-8) -> tuple[LeastSquaresFit, np.ndarray]:
    """IRLS of one agent (module docstring). Returns the fit (θ, standard errors, the
    unweighted residuals, the robust Q_i) and the final weights ω (m,)."""
    # start: least squares without the leverage points (robust distance of the velocity
    # regressor u^τ beyond χ²₂(0.999)), so a bad leverage point cannot set the start
    u = np.column_stack([reg.A_x[:, 0], reg.A_y[:, 0]])
    lever = outlier_weight(mahalanobis2(u - np.median(u, axis=0), mad_noise_cov(u)),
                           LEVERAGE_CHI2)
    fit = fit_agent(_weighted(reg, lever), ridge=ridge, se=se)
    fit = replace(fit, residuals=_residuals(reg, fit.theta))
    q = mad_noise_cov(fit.residuals)
    w = np.ones(reg.n_samples)
    theta = fit.theta
    for _ in range(max_iter):
        w = outlier_weight(mahalanobis2(fit.residuals, q))
        fit_w = fit_agent(_weighted(reg, w), ridge=ridge, se=se)
        th = fit_w.theta
        fit = replace(fit_w, residuals=_residuals(reg, th))
        q = robust_noise_cov(fit.residuals, w)
        step = np.max(np.abs(th - theta) / np.maximum(np.abs(theta), 1e-12))
        theta = th
        if step < tol:
            break
    w = outlier_weight(mahalanobis2(fit.residuals, q))
    return replace(fit, noise_cov=robust_noise_cov(fit.residuals, w)), w
