"""Offline smoothing on the herd clock: RTS smoother or the paper's causal Gaussian FIR.

* :func:`rts_on_ticks` — Rauch-Tung-Striebel (Rauch, Tung & Striebel, AIAA J. 3(8), 1965) run
  over each filter segment's accepted fixes (:func:`rts_timeline`: what
  :meth:`filterpy.kalman.KalmanFilter.rts_smoother` computes, its backward pass compiled),
  then carried to the ticks between fixes *within the filter's own model*: over the
  interval (t_k, t_{k+1}) the discrete white-noise acceleration model has one constant
  acceleration a, so x_t = F(τ) x_k + G(τ) a and x_{k+1} = F(Δ) x_k + G(Δ) a share it and

      C  = cov(x_t, x_{k+1} | z_{1:k}) = F(τ) P_k F(Δ)ᵀ + σ_a² G(τ) G(Δ)ᵀ ⊗ I₂
      J  = C P⁻_{k+1}⁻¹
      x̂_t = x⁻_t + J (x̂ˢ_{k+1} − x⁻_{k+1}),   P̂_t = P⁻_t + J (Pˢ_{k+1} − P⁻_{k+1}) Jᵀ

  (the RTS step with the tick as an extra state; Särkkä, *Bayesian Filtering and Smoothing*,
  2013, §8.2). Ticks after a segment's last fix carry its (smoothed = filtered) prediction.
  Each step is taken with the motion its state moved by (the prior, then each fitted
  model) and, for a graze/walk mixture filter, on the moments of the mixture's prior
  (:func:`_moment_steps`; the Gaussian RTS smoother, Särkkä 2013, §9.1), so the smoother
  assumes between fixes what the filter did.
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

from herd_ros.ingest.collar_filter import process_noise, transition
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
    from scipy.signal import lfilter, lfilter_zi      # (lazily: only the FIR needs it)
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


def _models(timeline: StateTimeline) -> tuple[np.ndarray, np.ndarray]:
    """(σ_a (K,), τ_v (K,)): the motion model that carries each state of ``timeline``
    forward (its ``motion``, or its one model), as the filter and the herd clock use it."""
    K = len(timeline.t)
    if timeline.motion is None:
        return np.full(K, float(timeline.accel_std)), np.full(K, float(timeline.velocity_tau))
    return timeline.motion[:, 0], timeline.motion[:, 1]


def _by_model(accel, vt):
    """(σ_a, τ_v, rows) for each distinct model of the (M,) arrays ``accel``, ``vt``."""
    accel = np.asarray(accel, dtype=float)
    vt = np.asarray(vt, dtype=float)
    if accel.size == 0:
        return []
    if np.all(accel == accel[0]) and np.all(vt == vt[0]):     # the common case: one model
        return [(float(accel[0]), float(vt[0]), slice(None))]
    uniq, inv = np.unique(accel + 1j * vt, return_inverse=True)
    inv = np.asarray(inv).reshape(-1)
    return [(float(u.real), float(u.imag), np.flatnonzero(inv == j))
            for j, u in enumerate(uniq)]


def _sandwich(A, P, B):
    """A P Bᵀ for stacks of 4 × 4 matrices."""
    return A @ P @ np.swapaxes(B, -1, -2)


def _mv(A, x):
    """A x for stacks of 4 × 4 matrices and 4-vectors."""
    return (A @ np.asarray(x, dtype=float)[..., :, None])[..., 0]


def _steps(tau, accel, vt):
    """``F(τ_m)`` and ``Q(τ_m)`` (M, 4, 4) of step m under the model (``accel[m]``,
    ``vt[m]``) (:func:`~herd_ros.ingest.collar_filter.transition`,
    :func:`~herd_ros.ingest.collar_filter.process_noise`)."""
    tau = np.asarray(tau, dtype=float)
    F = np.empty(tau.shape + (4, 4))
    Q = np.empty(tau.shape + (4, 4))
    for a, v, rows in _by_model(accel, vt):
        F[rows] = transition(tau[rows], v)
        Q[rows] = process_noise(tau[rows], a, v)
    return F, Q


def _components(timeline: StateTimeline, rows):
    """[(weight, σ_a (M,), τ_v (M,))]: the motion that carries the states ``rows``
    forward — their own model and, for a graze/walk mixture, the walk at its prior
    probability."""
    accel, vt = _models(timeline)
    a, v = accel[rows], vt[rows]
    if timeline.walk is None:
        return [(1.0, a, v)]
    wa, wv, pw = timeline.walk
    return [(1.0 - pw, a, v), (pw, np.full(a.shape, wa), np.full(v.shape, wv))]


def _moment_steps(x, P, tau, comps):
    """``F̄``, ``Q̄`` (M, 4, 4) of the motion ``comps`` (:func:`_components`) over ``tau``
    from the states (x (M, 4), P (M, 4, 4)), such that the prior of the next state has
    mean ``F̄ x``, covariance ``F̄ P F̄ᵀ + Q̄`` and covariance ``P F̄ᵀ`` with the state —
    the moments of the GPB1 filter's prior, the mixture over components j with weights
    w_j (Bar-Shalom, Li & Kirubarajan 2001, eq. 11.6.6-7)::

        F̄ = Σ w_j F_j,   Q̄ = Σ w_j (F_j P F_jᵀ + Q_j + (F_j − F̄) x xᵀ (F_j − F̄)ᵀ) − F̄ P F̄ᵀ

    With one component, ``F`` and ``Q`` themselves. The smoothers below are the Gaussian
    RTS smoother on these moments (Särkkä 2013, §9.1): with them an RTS pass over a
    mixture filter's states agrees with what the filter assumed between fixes."""
    return _moments(x, P, _component_steps(tau, comps))


def _component_steps(tau, comps):
    """[(w_j, F_j (M, 4, 4), Q_j (M, 4, 4))] of the motion ``comps`` over ``tau``."""
    return [(w, *_steps(tau, a, v)) for w, a, v in comps]


def _moments(x, P, parts):
    """:func:`_moment_steps` from the components' steps ``parts``
    (:func:`_component_steps`)."""
    if len(parts) == 1:
        return parts[0][1], parts[0][2]
    Fbar = sum(w * F for w, F, _ in parts)
    x = np.asarray(x, dtype=float)[..., :, None]
    mean = Fbar @ x
    Qbar = -_sandwich(Fbar, P, Fbar)
    for w, F, Q in parts:
        d = F @ x - mean
        Qbar += w * (_sandwich(F, P, F) + Q + d * np.swapaxes(d, -1, -2))
    return Fbar, 0.5 * (Qbar + np.swapaxes(Qbar, -1, -2))


def _backward_steps(timeline: StateTimeline, x, P, k):
    """What the backward recursions need of the steps k → k + 1 (``k`` indices): the
    prior's mean ``F_k x_k`` and covariance ``P⁻_{k+1} = F_k P_k F_kᵀ + Q_k`` and the gain
    ``J_k = P_k F_kᵀ (P⁻_{k+1})⁻¹``, each step by the motion state k moved with, on the
    moments of a mixture (:func:`_moment_steps`)."""
    F, Q = _moment_steps(x[k], P[k], timeline.t[k + 1] - timeline.t[k],
                         _components(timeline, k))
    Pp = _sandwich(F, P[k], F) + Q
    J = np.swapaxes(np.linalg.solve(Pp, F @ np.swapaxes(P[k], -1, -2)), -1, -2)
    return _mv(F, x[k]), Pp, J


def rts_timeline(timeline: StateTimeline) -> tuple[np.ndarray, np.ndarray]:
    """RTS-smoothed states at the timeline's own times, segment by segment:
    (x (K, 4), P (K, 4, 4)). The priors and gains of every step at once
    (:func:`_backward_steps`), then the backward recursion
    (:func:`herd_ros.ingest.collar_kernels.rts_backward`, compiled; a numpy loop where the
    kernels are absent) — what :meth:`filterpy.kalman.KalmanFilter.rts_smoother` computes
    step by step (``test_herd_clock.py`` checks it against filterpy)."""
    x = np.ascontiguousarray(timeline.x, dtype=float).reshape(-1, 4)
    P = np.ascontiguousarray(timeline.P, dtype=float).reshape(-1, 4, 4)
    xs, Ps = x.copy(), P.copy()
    K = len(x)
    if K < 2:
        return xs, Ps
    seg = np.asarray(timeline.segment)
    link = np.ascontiguousarray(seg[1:] == seg[:-1])
    if not link.any():
        return xs, Ps
    # only the steps within a segment
    k = np.flatnonzero(link)
    Fx, Pp, J = np.zeros((K - 1, 4)), np.zeros((K - 1, 4, 4)), np.zeros((K - 1, 4, 4))
    Fx[k], Pp[k], J[k] = _backward_steps(timeline, x, P, k)
    from herd_ros.ingest import collar_bank
    if collar_bank.AVAILABLE:
        collar_bank.KERNELS.rts_backward(link, x, Fx, P, Pp, J, xs, Ps)
        return xs, Ps
    for i in k[::-1]:
        xs[i] = x[i] + J[i] @ (xs[i + 1] - Fx[i])
        Ps[i] = P[i] + J[i] @ (Ps[i + 1] - Pp[i]) @ J[i].T
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
    xp, Pp, J = _backward_steps(timeline, x, P, np.arange(K - 1))
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
        cur_x[on] = x[ii] + _mv(J[ii], cur_x[on] - xp[ii])
        cur_P[on] = P[ii] + _sandwich(J[ii], cur_P[on] - Pp[ii], J[ii])
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
    comps = _components(timeline, k)    # the motion that carries state k to the tick
    to_tick = _component_steps(tau1, comps)
    # the filtered prediction from fix k to the tick (and the plain answer after a segment)
    f1, q1 = _moments(timeline.x[k], timeline.P[k], to_tick)
    xf = _mv(f1, timeline.x[k])
    Pf = _sandwich(f1, timeline.P[k], f1) + q1
    g1, r1 = _moments(xs[k], Ps[k], to_tick)
    xsp = _mv(g1, xs[k])
    Psp = _sandwich(g1, Ps[k], g1) + r1
    nxt = np.minimum(k + 1, K - 1)
    inside = have & (k + 1 < K) & (timeline.segment[nxt] == timeline.segment[k])
    x_out[have], P_out[have] = xsp[have], Psp[have]
    if inside.any():
        ki, kn, t1 = k[inside], nxt[inside], tau1[inside]
        delta = timeline.t[kn] - timeline.t[ki]
        xk, Pk = timeline.x[ki], timeline.P[ki]
        # C = cov(x(t1), x(δ) | fixes to k) = Σ w_j (F_j(t1) P F_j(δ)ᵀ + the noises'
        # covariance + the spread of the components' means), with x(δ)'s prior moments
        comps_in = [(w, a[inside], v[inside]) for w, a, v in comps]
        to_next = _component_steps(delta, comps_in)
        m1 = _mv(f1[inside], xk)
        f2, q2 = _moments(xk, Pk, to_next)
        m2 = _mv(f2, xk)
        c = np.zeros(t1.shape + (4, 4))
        for (w, a_in, v_in), (_, g1_all, _), (_, g2_j, _) in zip(comps_in, to_tick, to_next):
            g1_j = g1_all[inside]
            cross = np.empty(t1.shape + (4, 4))
            for a, v, rows in _by_model(a_in, v_in):
                if v > 0:
                    # a Markov (continuous) model: x(δ) = F(δ − t1) x(t1) + independent
                    # noise, so the noise to t1 and to δ covary as Q(t1) F(δ − t1)ᵀ
                    cross[rows] = process_noise(t1[rows], a, v) @ np.swapaxes(
                        transition(delta[rows] - t1[rows], v), -1, -2)
                else:
                    cross[rows] = _gain_matrix((t1[rows], delta[rows]), a)
            d1 = _mv(g1_j, xk) - m1
            d2 = _mv(g2_j, xk) - m2
            c += w * (_sandwich(g1_j, Pk, g2_j) + cross + d1[..., :, None] * d2[..., None, :])
        P_next_prior = _sandwich(f2, Pk, f2) + q2
        gain = np.linalg.solve(P_next_prior, np.swapaxes(c, -1, -2))
        gain = np.swapaxes(gain, -1, -2)                   # J = C P⁻⁻¹ (P⁻ symmetric)
        dx = xs[kn] - m2
        dP = Ps[kn] - P_next_prior
        x_out[inside] = xf[inside] + _mv(gain, dx)
        P_out[inside] = Pf[inside] + _sandwich(gain, dP, gain)
    return x_out, P_out
