"""Offline smoothing on the herd clock: RTS smoother or the paper's causal Gaussian FIR.

* :func:`rts_on_ticks` — Rauch-Tung-Striebel (Rauch, Tung & Striebel, AIAA J. 3(8), 1965) run
  with :meth:`filterpy.kalman.KalmanFilter.rts_smoother` over each filter segment's accepted
  fixes, then carried to the ticks between fixes *within the filter's own model*: over the
  interval (t_k, t_{k+1}) the discrete white-noise acceleration model has one constant
  acceleration a, so x_t = F(τ) x_k + G(τ) a and x_{k+1} = F(Δ) x_k + G(Δ) a share it and

      C  = cov(x_t, x_{k+1} | z_{1:k}) = F(τ) P_k F(Δ)ᵀ + σ_a² G(τ) G(Δ)ᵀ ⊗ I₂
      J  = C P⁻_{k+1}⁻¹
      x̂_t = x⁻_t + J (x̂ˢ_{k+1} − x⁻_{k+1}),   P̂_t = P⁻_t + J (Pˢ_{k+1} − P⁻_{k+1}) Jᵀ

  (the RTS step with the tick as an extra state; Särkkä, *Bayesian Filtering and Smoothing*,
  2013, §8.2). Ticks after a segment's last fix carry its (smoothed = filtered) prediction.
* :func:`fixed_lag_timeline` — the fixed-lag smoother: each state given the next ``lag``
  fixes only (a delay of ``lag`` fixes instead of the whole recording), carried to the
  ticks the same way.
* :func:`gaussian_fir` — the paper's causal FIR (Schwager et al. 2007):
  ``y[t] = Σ_{j=0}^{n-1} b_j p[t-j]``, ``b_j ∝ exp(-j²/2σ²)``, Σ b_j = 1, n = 30, σ = 6 steps,
  with :func:`scipy.signal.lfilter`, the history before the first tick held at the first
  value. Its group delay is Σ j b_j ≈ σ√(2/π) ≈ 4.8 steps (the paper accepts that lag).
"""
from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.signal import lfilter, lfilter_zi

from herd_ros.ingest.collar_filter import predict_state, process_noise, transition
from herd_ros.ingest.herd_clock import StateTimeline


def gaussian_fir_taps(n: int = 30, sigma: float = 6.0) -> np.ndarray:
    """``b_j = exp(-j²/2σ²) / Σ_k exp(-k²/2σ²)``, j = 0..n-1 (Schwager et al. 2007)."""
    if n < 1 or not sigma > 0:
        raise ValueError(f'FIR needs n >= 1 and sigma > 0, got n={n}, sigma={sigma}')
    j = np.arange(n, dtype=float)
    b = np.exp(-j * j / (2.0 * sigma * sigma))
    return b / b.sum()


def gaussian_fir(positions, n: int = 30, sigma: float = 6.0) -> np.ndarray:
    """Causal Gaussian FIR along axis 0 (the uniform clock) of ``positions`` (T, ...).

    The filter starts from rest at the first sample (history = ``positions[0]``), so a
    constant input passes unchanged. Must be finite (trim NaN ends first).
    """
    p = np.asarray(positions, dtype=float)
    b = gaussian_fir_taps(n, sigma)
    if len(p) == 0:
        return p.copy()
    zi = lfilter_zi(b, [1.0]).reshape((-1,) + (1,) * (p.ndim - 1)) * p[0][None]
    y, _ = lfilter(b, [1.0], p, axis=0, zi=zi)
    return y


def _gain_matrix(tau, accel_std):
    """σ_a² G(τ1) G(τ2)ᵀ ⊗ I₂ for the state [e, n, ve, vn]; tau1, tau2 (...,) -> (..., 4, 4)."""
    t1, t2 = tau
    var = float(accel_std) ** 2
    g1 = np.stack([t1 * t1 / 2.0, t1], axis=-1)          # (..., 2)
    g2 = np.stack([t2 * t2 / 2.0, t2], axis=-1)
    gg = var * g1[..., :, None] * g2[..., None, :]       # (..., 2, 2) over (pos, vel)
    out = np.zeros(np.shape(t1) + (4, 4))
    for a in range(2):
        for b in range(2):
            out[..., 2 * a, 2 * b] = gg[..., a, b]
            out[..., 2 * a + 1, 2 * b + 1] = gg[..., a, b]
    return out


def rts_timeline(timeline: StateTimeline) -> tuple[np.ndarray, np.ndarray]:
    """RTS-smoothed states at the timeline's own times, segment by segment:
    (x (K, 4), P (K, 4, 4))."""
    xs = timeline.x.copy()
    Ps = timeline.P.copy()
    kf = KalmanFilter(dim_x=4, dim_z=2)
    seg = timeline.segment
    for s in np.unique(seg):
        idx = np.flatnonzero(seg == s)
        if len(idx) < 2:
            continue
        tau = np.concatenate([[0.0], np.diff(timeline.t[idx])])
        Fs = transition(tau, timeline.velocity_tau)
        Qs = process_noise(tau, timeline.accel_std, timeline.velocity_tau)
        x_s, P_s, _, _ = kf.rts_smoother(timeline.x[idx], timeline.P[idx], Fs, Qs)
        xs[idx], Ps[idx] = x_s, P_s
    return xs, Ps


def fixed_lag_timeline(timeline: StateTimeline, lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-lag smoothed states at the timeline's own times: state k given the fixes up
    to k + ``lag`` of its segment (x (K, 4), P (K, 4, 4)) — the RTS recursion run back
    from k + lag to k (Särkkä 2013, §8.2; Moore 1973, the fixed-lag smoother as a
    truncated fixed-interval one), vectorised over k::

        x̂_i = x_i + J_i (x̂_{i+1} − F_i x_i),  P̂_i = P_i + J_i (P̂_{i+1} − P⁻_{i+1}) J_iᵀ,
        J_i = P_i F_iᵀ (P⁻_{i+1})⁻¹

    ``lag`` 0 returns the filtered states; a lag as long as the segment, the RTS smoother's.
    What the estimator would learn from with a delay of ``lag`` fixes."""
    lag = int(lag)
    if lag < 0:
        raise ValueError(f'lag must be >= 0 fixes, got {lag}')
    x, P = timeline.x, timeline.P
    K = len(timeline.t)
    xs, Ps = x.copy(), P.copy()
    if K < 2 or lag == 0:
        return xs, Ps
    tau = np.diff(timeline.t)
    F = transition(tau, timeline.velocity_tau)
    Q = process_noise(tau, timeline.accel_std, timeline.velocity_tau)
    xp = np.einsum('kij,kj->ki', F, x[:-1])
    Pp = np.einsum('kij,kjl,kml->kim', F, P[:-1], F) + Q
    J = np.swapaxes(np.linalg.solve(Pp, np.einsum('kij,klj->kil', F, P[:-1])), -1, -2)
    seg = timeline.segment
    # the last state each k may use: k + lag, within k's segment
    seg_end = np.searchsorted(seg, seg, side='right') - 1    # segments never decrease
    end = np.minimum(np.arange(K) + lag, seg_end)
    cur_x, cur_P = x[end].copy(), P[end].copy()
    for s in range(lag - 1, -1, -1):
        i = np.arange(K) + s
        on = i < end
        if not on.any():
            continue
        ii = i[on]
        cur_x[on] = x[ii] + np.einsum('kij,kj->ki', J[ii], cur_x[on] - xp[ii])
        cur_P[on] = P[ii] + np.einsum('kij,kjl,kml->kim', J[ii], cur_P[on] - Pp[ii], J[ii])
    return cur_x, cur_P


def rts_on_ticks(timeline: StateTimeline, ticks, lag: int | None = None):
    """RTS-smoothed estimates at ``ticks`` (T,): (x (T, 4), P (T, 4, 4)); NaN before the
    first fix. See the module docstring for the in-between-fix step. ``lag`` (fixes): the
    fixed-lag smoother instead (:func:`fixed_lag_timeline`), each tick given the fixes up
    to ``lag`` after it."""
    ticks = np.asarray(ticks, dtype=float)
    T = len(ticks)
    x_out = np.full((T, 4), np.nan)
    P_out = np.full((T, 4, 4), np.nan)
    K = len(timeline.t)
    if K == 0:
        return x_out, P_out
    xs, Ps = rts_timeline(timeline) if lag is None else fixed_lag_timeline(timeline, lag)
    k = np.searchsorted(timeline.t, ticks, side='right') - 1
    have = k >= 0
    k = np.where(have, k, 0)
    tau1 = ticks - timeline.t[k]
    # the filtered prediction from fix k to the tick (and the plain answer after a segment)
    vt = timeline.velocity_tau
    xf, Pf = predict_state(timeline.x[k], timeline.P[k], tau1, timeline.accel_std, vt)
    xsp, Psp = predict_state(xs[k], Ps[k], tau1, timeline.accel_std, vt)
    nxt = np.minimum(k + 1, K - 1)
    inside = have & (k + 1 < K) & (timeline.segment[nxt] == timeline.segment[k])
    x_out[have], P_out[have] = xsp[have], Psp[have]
    if inside.any():
        ki, kn, t1 = k[inside], nxt[inside], tau1[inside]
        delta = timeline.t[kn] - timeline.t[ki]
        f1, f2 = transition(t1, vt), transition(delta, vt)
        Pk = timeline.P[ki]
        if vt > 0:
            # a Markov (continuous) model: x(δ) = F(δ − t1) x(t1) + independent noise, so the
            # noise to t1 and to δ covary as Q(t1) F(δ − t1)ᵀ
            cross = np.einsum('...ij,...kj->...ik', process_noise(t1, timeline.accel_std, vt),
                              transition(delta - t1, vt))
        else:
            cross = _gain_matrix((t1, delta), timeline.accel_std)
        c = np.einsum('...ij,...jk,...lk->...il', f1, Pk, f2) + cross
        x_next_prior, P_next_prior = predict_state(timeline.x[ki], Pk, delta,
                                                   timeline.accel_std, vt)
        gain = np.linalg.solve(P_next_prior, np.swapaxes(c, -1, -2))
        gain = np.swapaxes(gain, -1, -2)                   # J = C P⁻⁻¹ (P⁻ symmetric)
        dx = xs[kn] - x_next_prior
        dP = Ps[kn] - P_next_prior
        x_out[inside] = xf[inside] + np.einsum('...ij,...j->...i', gain, dx)
        P_out[inside] = Pf[inside] + np.einsum('...ij,...jk,...lk->...il', gain, dP, gain)
    return x_out, P_out
