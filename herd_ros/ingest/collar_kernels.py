"""The compiled loops of the collar bank and of the streaming herd clock.

Everything here is numba-typed scalar code: the 2 × 2 / 4 × 4 algebra of the reference
filter (:mod:`herd_ros.ingest.collar_filter`, whose docstring cites the equations) written
out entry by entry, over arrays of collars. The public entry points are listed, with their
argument types, in :data:`herd_ros.ingest.aot.EXPORTS`. They are compiled one of two ways:

* **ahead of time**, once, at install: ``setup.py`` builds the extension module
  ``herd_ros.ingest._collar_kernels`` from this file with ``numba.pycc``
  (:mod:`herd_ros.ingest.aot`); a process that loads it never imports numba;
* **just in time**, where the extension is absent (no C compiler at install, a source
  checkout): numba compiles these functions on first call and caches the machine code in
  ``__pycache__`` (``cache=True``, as the RLS kernel).

Callers go through :data:`herd_ros.ingest.collar_bank.KERNELS`, never through this module,
which imports numba.
"""
import math

import numpy as np
from numba import njit

from herd_ros.ingest.fix_outcomes import (ACCEPTED, C_ACC, C_GATE, C_NAN, C_NO_FIX,
                                          C_RANGE, C_REINIT, C_SPEED, C_TIME, C_UNCONF,
                                          GATE, MAX_CANDIDATES, NAN, NO_FIX, RANGE,
                                          REINITIALISED, SPEED, STATUS_NO_FIX, TIME,
                                          UNCONFIRMED)

def _jit(fn):
    return njit(cache=True, nogil=True)(fn)


@_jit
def covariances(cov_type, c, d2, f2, r):
    """The loop of :func:`measurement_covariances` (``d2``, ``f2`` (M,): each fix's default
    variance and floor, its collar's)."""
    for m in range(cov_type.shape[0]):
        t = cov_type[m]
        known = (t != 0 and math.isfinite(c[m, 0]) and math.isfinite(c[m, 1])
                 and math.isfinite(c[m, 3]) and math.isfinite(c[m, 4]))
        if known:
            a = c[m, 0]
            cc = c[m, 4]
            b = 0.0 if t == 2 else 0.5 * (c[m, 1] + c[m, 3])
        else:
            a = d2[m]
            cc = d2[m]
            b = 0.0
        mid = 0.5 * (a + cc)
        d = math.hypot(0.5 * (a - cc), b)
        l1 = mid - d
        l2 = mid + d
        if l1 >= f2[m]:
            r[m, 0, 0] = a
            r[m, 1, 1] = cc
            r[m, 0, 1] = r[m, 1, 0] = b
            continue
        L1 = max(l1, f2[m])
        L2 = max(l2, f2[m])
        w = (L1 - L2) / (-2.0 * d) if d > 0 else 0.0       # (L1 − L2)/(λ₁ − λ₂)
        r[m, 0, 0] = L2 + w * (a - l2)
        r[m, 1, 1] = L2 + w * (cc - l2)
        r[m, 0, 1] = r[m, 1, 0] = w * b


@_jit
def _reach(tau, max_speed, cruise_speed, sprint_s):
    """d_max(τ) of FilterParams.reach."""
    if tau < 0.0:
        tau = 0.0
    sprint = min(tau, sprint_s)
    return max_speed * sprint + cruise_speed * (tau - sprint)


@_jit
def _max_eig(a, b, c):
    """Largest eigenvalue of the symmetric [[a, b], [b, c]]."""
    return 0.5 * (a + c) + math.hypot(0.5 * (a - c), b)


@_jit
def _motion(tau, accel_std, velocity_tau):
    """(f_pv, f_vv, q_pp, q_pv, q_vv): the entries of F(τ) and Q(τ) (transition,
    process_noise)."""
    var = accel_std * accel_std
    if velocity_tau > 0.0:
        if tau < 0.0:
            tau = 0.0
        beta = 1.0 / velocity_tau
        a = -math.expm1(-beta * tau)          # 1 − e^{−βτ}
        b = a * (2.0 - a)                     # 1 − e^{−2βτ} = 1 − (1 − a)²
        f_pv = a / beta
        f_vv = 1.0 - a
        vv = var / (2.0 * beta) * b
        pv = var / (2.0 * beta ** 2) * a ** 2
        pp = var / beta ** 2 * (tau - 2.0 * a / beta + b / (2.0 * beta))
        if pp < 0.0:
            pp = 0.0
        return f_pv, f_vv, pp, pv, vv
    return tau, 1.0, var * tau ** 4 / 4.0, var * tau ** 3 / 2.0, var * tau ** 2


@_jit
def _sandwich(A, P, out, AP):
    """out = A P Aᵀ (4 × 4), summed in the order of the matrix products (``AP`` a 4 × 4
    scratch)."""
    for i in range(4):
        for j in range(4):
            s = 0.0
            for k in range(4):
                s += A[i, k] * P[k, j]
            AP[i, j] = s
    for i in range(4):
        for j in range(4):
            s = 0.0
            for k in range(4):
                s += AP[i, k] * A[j, k]
            out[i, j] = s


@_jit
def _predict(x, P, tau, accel_std, velocity_tau, xo, Po, W):
    """xo = F x, Po = F P Fᵀ + Q (filterpy's predict); ``W`` (≥ 2, 4, 4) scratch (the
    kernels allocate it once per call, not once per fix)."""
    f_pv, f_vv, pp, pv, vv = _motion(tau, accel_std, velocity_tau)
    F = W[0]
    F[:, :] = 0.0
    F[0, 0] = F[1, 1] = 1.0
    F[0, 2] = F[1, 3] = f_pv
    F[2, 2] = F[3, 3] = f_vv
    for i in range(4):
        s = 0.0
        for j in range(4):
            s += F[i, j] * x[j]
        xo[i] = s
    _sandwich(F, P, Po, W[1])
    for i in range(2):
        Po[i, i] += pp
        Po[i, i + 2] += pv
        Po[i + 2, i] += pv
        Po[i + 2, i + 2] += vv


@_jit
def predict_many(x, P, tau, accel_std, velocity_tau, xo, Po):
    """Each state predicted over its own interval with its own motion model (arrays)."""
    W = np.empty((4, 4, 4))
    for m in range(x.shape[0]):
        _predict(x[m], P[m], tau[m], accel_std[m], velocity_tau[m], xo[m], Po[m], W)


@_jit
def predict_gathered(g, dest, tau, x, P, motion, out_x, out_P):
    """``out_x[dest[m]]``, ``out_P[dest[m]]`` = state ``g[m]`` of ``x`` (K, 4), ``P``
    (K, 4, 4) predicted over ``tau[m]`` with its motion model ``motion[g[m]]`` (σ_a, τ_v):
    :func:`predict_many` of the gathered states, written where they go (the herd clock's
    ticks, ``herd_clock.states_at``) without the gathered copies; ``out_P`` (·, 2, 2)
    keeps the position block alone."""
    W = np.empty((4, 4, 4))
    xo = np.empty(4)
    Po = np.empty((4, 4))
    block = out_P.shape[1]
    for m in range(g.shape[0]):
        k = g[m]
        d = dest[m]
        _predict(x[k], P[k], tau[m], motion[k, 0], motion[k, 1], xo, Po, W)
        for i in range(4):
            out_x[d, i] = xo[i]
        for i in range(block):
            for j in range(block):
                out_P[d, i, j] = Po[i, j]


@_jit
def _update(x, P, z0, z1, R, W):
    """filterpy's update with H = [I 0]: K = P Hᵀ S⁻¹, x += K y,
    P = (I − KH) P (I − KH)ᵀ + K R Kᵀ (Joseph form), in place; ``W`` (4, 4, 4) scratch."""
    y0 = z0 - x[0]
    y1 = z1 - x[1]
    s00 = P[0, 0] + R[0, 0]
    s01 = P[0, 1] + R[0, 1]
    s10 = P[1, 0] + R[1, 0]
    s11 = P[1, 1] + R[1, 1]
    det = s00 * s11 - s01 * s10
    i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
    K = W[0]
    for i in range(4):
        K[i, 0] = P[i, 0] * i00 + P[i, 1] * i10
        K[i, 1] = P[i, 0] * i01 + P[i, 1] * i11
    for i in range(4):
        x[i] += K[i, 0] * y0 + K[i, 1] * y1
    A = W[1]                      # I − K H
    A[:, :] = 0.0
    for i in range(4):
        A[i, i] = 1.0
        A[i, 0] -= K[i, 0]
        A[i, 1] -= K[i, 1]
    KR = W[2]
    for i in range(4):
        KR[i, 0] = K[i, 0] * R[0, 0] + K[i, 1] * R[1, 0]
        KR[i, 1] = K[i, 0] * R[0, 1] + K[i, 1] * R[1, 1]
    _sandwich(A, P, P, W[3])
    for i in range(4):
        for j in range(4):
            P[i, j] += KR[i, 0] * K[j, 0] + KR[i, 1] * K[j, 1]


@_jit
def _mahalanobis2(xp, Pp, z0, z1, r):
    """(yᵀ S⁻¹ y, det S) of the innovation y = z − x⁻[:2], S = P⁻[:2, :2] + R."""
    y0 = z0 - xp[0]
    y1 = z1 - xp[1]
    s00 = Pp[0, 0] + r[0, 0]
    s01 = Pp[0, 1] + r[0, 1]
    s10 = Pp[1, 0] + r[1, 0]
    s11 = Pp[1, 1] + r[1, 1]
    det = s00 * s11 - s01 * s10
    return (y0 * (s11 * y0 - s01 * y1) + y1 * (s00 * y1 - s10 * y0)) / det, det


@_jit
def _collapse(xa, Pa, xb, Pb, wa, wb, xo, Po):
    """Moment matching of a two-component mixture (Bar-Shalom, Li & Kirubarajan 2001,
    eq. 11.6.6-7): x = Σ w_j x_j, P = Σ w_j (P_j + (x_j − x)(x_j − x)ᵀ)."""
    for i in range(4):
        xo[i] = wa * xa[i] + wb * xb[i]
    for i in range(4):
        for j in range(4):
            Po[i, j] = (wa * (Pa[i, j] + (xa[i] - xo[i]) * (xa[j] - xo[j]))
                        + wb * (Pb[i, j] + (xb[i] - xo[i]) * (xb[j] - xo[j])))


@_jit
def _reach_ratio(i, c, stamp, z0, z1, r, cand_len, cand_t, cand_z, cand_r,
                 max_speed, cruise_speed, sprint_s, gate_sigma):
    """CollarFilter._reach_ratio: smallest distance / allowed reach over the chain's
    fixes; inf unless the fix is after the chain's last."""
    n = cand_len[i, c]
    if not stamp > cand_t[i, c, n - 1]:
        return np.inf
    best = np.inf
    for k in range(n):
        rp = cand_r[i, c, k]
        sigma = math.sqrt(_max_eig(r[0, 0] + rp[0, 0], r[1, 0] + rp[1, 0],
                                   r[1, 1] + rp[1, 1]))
        allowed = _reach(stamp - cand_t[i, c, k], max_speed, cruise_speed,
                         sprint_s) + gate_sigma * sigma
        ratio = math.hypot(z0 - cand_z[i, c, k, 0], z1 - cand_z[i, c, k, 1]) / allowed
        if ratio < best:
            best = ratio
    return best


@_jit
def _chain_distance(i, c, z0, z1, cand_len, cand_z):
    best = np.inf
    for k in range(cand_len[i, c]):
        d = math.hypot(z0 - cand_z[i, c, k, 0], z1 - cand_z[i, c, k, 1])
        if d < best:
            best = d
    return best


@_jit
def _far(i, z0, z1, rng, sigmas, margin, min_fixes):
    """collar_filter.outside_range for collar i: ``rng`` (N, 6) = [n, Σx, Σy, Σx², Σxy,
    Σy²] of its accepted states."""
    n = rng[i, 0]
    if sigmas <= 0.0 or n < max(min_fixes, 1):
        return False
    mx = rng[i, 1] / n
    my = rng[i, 2] / n
    a = rng[i, 3] / n - mx * mx + 1.0
    b = rng[i, 4] / n - mx * my
    c = rng[i, 5] / n - my * my + 1.0
    dx = z0 - mx
    dy = z1 - my
    det = a * c - b * b
    r2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det
    top = 0.5 * (a + c) + math.sqrt(0.25 * (a - c) * (a - c) + b * b)
    return r2 > sigmas * sigmas and math.hypot(dx, dy) - 3.0 * math.sqrt(top) > margin


@_jit
def _attach(i, chain, stamp, z0, z1, r, jump, n_cand, cand_jump, cand_len, cand_t, cand_z,
            cand_r, max_speed, cruise_speed, sprint_s, gate_sigma, near=False):
    """CollarFilter._attach: append the fix to ``chain`` (≥ 0), the newest consistent
    chain (not one that began with a jump when the fix is ``near``), or a new one
    (dropping the oldest beyond MAX_CANDIDATES); its index."""
    if chain < 0:
        for c in range(n_cand[i] - 1, -1, -1):
            if near and cand_jump[i, c]:
                continue
            if _reach_ratio(i, c, stamp, z0, z1, r, cand_len, cand_t, cand_z, cand_r,
                            max_speed, cruise_speed, sprint_s, gate_sigma) <= 1.0:
                chain = c
                break
    if chain < 0:
        if n_cand[i] == MAX_CANDIDATES:
            for c in range(MAX_CANDIDATES - 1):
                cand_jump[i, c] = cand_jump[i, c + 1]
                cand_len[i, c] = cand_len[i, c + 1]
                cand_t[i, c] = cand_t[i, c + 1]
                cand_z[i, c] = cand_z[i, c + 1]
                cand_r[i, c] = cand_r[i, c + 1]
            n_cand[i] -= 1
        chain = n_cand[i]
        n_cand[i] += 1
        cand_jump[i, chain] = jump
        cand_len[i, chain] = 0
    k = cand_len[i, chain]
    cand_t[i, chain, k] = stamp
    cand_z[i, chain, k, 0] = z0
    cand_z[i, chain, k, 1] = z1
    cand_r[i, chain, k] = r
    cand_len[i, chain] = k + 1
    return chain


@_jit
def _seat(xi, Pi, z0, z1, r, v0):
    """The state on one fix: position z (covariance r), velocity 0 (std v0)."""
    xi[0] = z0
    xi[1] = z1
    xi[2] = 0.0
    xi[3] = 0.0
    Pi[:, :] = 0.0
    Pi[0, 0] = r[0, 0]
    Pi[0, 1] = r[0, 1]
    Pi[1, 0] = r[1, 0]
    Pi[1, 1] = r[1, 1]
    Pi[2, 2] = Pi[3, 3] = v0 * v0


@_jit
def _adopt(i, chain, t, x, P, ever, counters, n_cand, cand_len, cand_t, cand_z, cand_r,
           accel_std, velocity_tau, v0, gate, W):
    """CollarFilter._adopt: re-initialise on the chain's first fix, update through the
    rest; a fix outside the ``gate`` of that track starts it afresh (``W``: the scratch
    of :func:`_predict`)."""
    xi = x[i]
    Pi = P[i]
    _seat(xi, Pi, cand_z[i, chain, 0, 0], cand_z[i, chain, 0, 1], cand_r[i, chain, 0], v0)
    t[i] = cand_t[i, chain, 0]
    xp = np.empty(4)
    Pp = np.empty((4, 4))
    for k in range(1, cand_len[i, chain]):
        z0 = cand_z[i, chain, k, 0]
        z1 = cand_z[i, chain, k, 1]
        _predict(xi, Pi, cand_t[i, chain, k] - t[i], accel_std, velocity_tau, xp, Pp, W)
        d2, _ = _mahalanobis2(xp, Pp, z0, z1, cand_r[i, chain, k])
        if d2 > gate:
            _seat(xi, Pi, z0, z1, cand_r[i, chain, k], v0)
        else:
            xi[:] = xp
            Pi[:, :] = Pp
            _update(xi, Pi, z0, z1, cand_r[i, chain, k], W)
        t[i] = cand_t[i, chain, k]
    n_cand[i] = 0
    ever[i] = True
    counters[i, C_ACC] += 1


@_jit
def _held(left, i):
    """An accepted fix at the track's place: one fewer for each place it left (each
    dropped at zero: the new place has held)."""
    for o in (0, 8):
        if math.isfinite(left[i, o]):
            left[i, o + 6] -= 1.0
            if left[i, o + 6] <= 0.0:
                left[i, o] = np.nan


@_jit
def _forget_left(left, i):
    """CollarFilter._forget_places: neither place the track left is held any more."""
    left[i, 0] = np.nan
    left[i, 8] = np.nan


@_jit
def _keep_left(left, i, o, t, x, P, reacquire, for_chain):
    """Keep the place collar i's track is at (its state's time, position and position
    covariance) as the place it leaves, in the slot at column ``o`` (0: CollarFilter
    .left_place, 8: .left_recent), for ``reacquire`` accepted fixes; ``for_chain`` 1.0
    when it leaves for a reachable chain, 0.0 for a fix its walk component took."""
    left[i, o + 0] = t[i]
    left[i, o + 1] = x[i, 0]
    left[i, o + 2] = x[i, 1]
    left[i, o + 3] = P[i, 0, 0]
    left[i, o + 4] = P[i, 1, 0]
    left[i, o + 5] = P[i, 1, 1]
    left[i, o + 6] = reacquire
    left[i, o + 7] = for_chain


@_jit
def _return_to_left(i, s, z0, z1, r, left, accel_std, velocity_tau, gate, t, x, P, xp, Pp,
                    W):
    """CollarFilter._return_to_left: a refused fix inside the gate of a place the track
    left (the later of the two held first) goes back there at once (True)."""
    first = 8 if math.isfinite(left[i, 8]) and not left[i, 8] <= left[i, 0] else 0
    for o in (first, 8 - first):
        if math.isfinite(left[i, o]) and _return_to_left_at(
                i, o, s, z0, z1, r, left, accel_std, velocity_tau, gate, t, x, P, xp, Pp,
                W):
            return True
    return False


@_jit
def _return_to_left_at(i, o, s, z0, z1, r, left, accel_std, velocity_tau, gate, t, x, P,
                       xp, Pp, W):
    """CollarFilter._return_to: a refused fix inside the gate of the place in the slot at
    column ``o`` goes back there at once (True; the state updated with the fix)."""
    x0 = np.zeros(4)
    P0 = np.zeros((4, 4))
    x0[0] = left[i, o + 1]
    x0[1] = left[i, o + 2]
    P0[0, 0] = left[i, o + 3]
    P0[1, 0] = P0[0, 1] = left[i, o + 4]
    P0[1, 1] = left[i, o + 5]
    _predict(x0, P0, s - left[i, o], accel_std, velocity_tau, xp, Pp, W)
    d2, det = _mahalanobis2(xp, Pp, z0, z1, r)
    if not d2 <= gate:
        return False
    _update(xp, Pp, z0, z1, r, W)
    x[i, :] = xp
    P[i, :, :] = Pp
    t[i] = s
    _forget_left(left, i)
    return True


@_jit
def process_batch(collar, stamp, east, north, status, R,
                   t, x, P, ever, last_pos, last_report, counters, n_cand, cand_jump,
                   cand_len, cand_t, cand_z, cand_r, rng, left,
                   accel_std, velocity_tau, max_speed, cruise_speed, sprint_s, gate,
                   gate_sigma, v0, confirm, reacquire, confirm_lost, reinit_after_gap,
                   range_sigmas, range_margin, range_min,
                   walk_accel, walk_tau, walk_prob, walk_r2,
                   out_code, out_d2, out_x, out_P, out_seg):
    """CollarFilter.update for each fix of the batch, in order (see its comments);
    ``accel_std`` and ``velocity_tau`` are per collar (N,); ``walk_accel`` ≤ 0 = no walk
    component (else the motion mixture of FilterParams.walk, prior weight ``walk_prob``,
    its fixes' variance raised by ``walk_r2``); ``rng`` (N, 6) the moments of each
    collar's accepted states (its range: a chain far outside it needs ``reacquire``);
    ``left`` (N, 16): two slots of [t, e, n, r_ee, r_en, r_nn, fixes left, for a chain],
    the place each collar's track left when it last moved to a reachable chain (last
    column 1) or took a fix by its walk component alone (0) (t NaN: none;
    CollarFilter.left_place), and from column 8 the place it left at a later fix its
    walk component took while the first is held (CollarFilter.left_recent)."""
    xp = np.empty(4)
    Pp = np.empty((4, 4))
    xw = np.empty(4)
    Pw = np.empty((4, 4))
    rw = np.empty((2, 2))
    W = np.empty((4, 4, 4))         # the predicts' and updates' scratch
    keep_P = out_P.shape[0] > 0
    for m in range(collar.shape[0]):
        i = collar[m]
        s = stamp[m]
        z0 = east[m]
        z1 = north[m]
        r = R[m]
        code = -1
        d2 = np.nan
        if math.isfinite(s):
            if math.isnan(last_report[i]) or s > last_report[i]:
                last_report[i] = s
        if status[m] == STATUS_NO_FIX:
            code = NO_FIX
            counters[i, C_NO_FIX] += 1
        elif not (math.isfinite(z0) and math.isfinite(z1)):
            code = NAN
            counters[i, C_NAN] += 1
        elif not math.isfinite(s):
            code = TIME
            counters[i, C_TIME] += 1
        else:
            latest = t[i] if math.isfinite(t[i]) else -np.inf
            for c in range(n_cand[i]):
                latest = max(latest, cand_t[i, c, cand_len[i, c] - 1])
            if s <= latest:
                code = TIME
                counters[i, C_TIME] += 1
        if code < 0:
            silence = s - last_pos[i]
            last_pos[i] = s
            if math.isfinite(t[i]) and silence > reinit_after_gap:
                t[i] = np.nan               # the track is lost
                n_cand[i] = 0
                _forget_left(left, i)
            chain = -1
            reason = -1                     # rejection reason if the chain is not adopted
            if not math.isfinite(t[i]):
                far = _far(i, z0, z1, rng, range_sigmas, range_margin, range_min)
                chain = _attach(i, -1, s, z0, z1, r, far, n_cand, cand_jump, cand_len,
                                cand_t, cand_z, cand_r, max_speed, cruise_speed, sprint_s,
                                gate_sigma, not far)
                if far:
                    cand_jump[i, chain] = True  # a fix far outside the range: a jump
                if cand_len[i, chain] < (reacquire if cand_jump[i, chain] else confirm_lost):
                    code = UNCONFIRMED
                    counters[i, C_UNCONF] += 1
                else:
                    first = not ever[i]
                    _forget_left(left, i)
                    _adopt(i, chain, t, x, P, ever, counters, n_cand, cand_len, cand_t,
                           cand_z, cand_r, accel_std[i], velocity_tau[i], v0, gate, W)
                    if first:
                        code = ACCEPTED
                    else:
                        code = REINITIALISED
                        counters[i, C_REINIT] += 1
            else:
                xi = x[i]
                Pi = P[i]
                tau = s - t[i]
                dist = math.hypot(z0 - xi[0], z1 - xi[1])
                sigma = math.sqrt(_max_eig(r[0, 0] + Pi[0, 0], r[1, 0] + Pi[1, 0],
                                           r[1, 1] + Pi[1, 1]))
                allowed = _reach(tau, max_speed, cruise_speed, sprint_s) + gate_sigma * sigma
                if dist > allowed:
                    reason = SPEED
                    # beyond reach of the track, maybe not of the place it left
                    jump = True
                    if math.isfinite(left[i, 0]) and left[i, 7] > 0.0:
                        sl = math.sqrt(_max_eig(r[0, 0] + left[i, 3], r[1, 0] + left[i, 4],
                                                r[1, 1] + left[i, 5]))
                        jump = math.hypot(z0 - left[i, 1], z1 - left[i, 2]) > _reach(
                            s - left[i, 0], max_speed, cruise_speed, sprint_s) \
                            + gate_sigma * sl
                    chain = _attach(i, -1, s, z0, z1, r, jump, n_cand, cand_jump, cand_len,
                                    cand_t, cand_z, cand_r, max_speed, cruise_speed,
                                    sprint_s, gate_sigma)
                else:
                    _predict(xi, Pi, tau, accel_std[i], velocity_tau[i], xp, Pp, W)
                    d2, det = _mahalanobis2(xp, Pp, z0, z1, r)
                    gate_d2 = d2
                    if walk_accel > 0.0:
                        # the walk component of the motion mixture (FilterParams.walk)
                        _predict(xi, Pi, tau, walk_accel, walk_tau, xw, Pw, W)
                        rw[0, 0] = r[0, 0] + walk_r2
                        rw[1, 1] = r[1, 1] + walk_r2
                        rw[0, 1] = r[0, 1]
                        rw[1, 0] = r[1, 0]
                        d2w, detw = _mahalanobis2(xw, Pw, z0, z1, rw)
                        gate_d2 = min(d2, d2w)      # an outlier under both components
                    y0 = z0 - xp[0]
                    y1 = z1 - xp[1]
                    innovation = math.hypot(y0, y1)
                    # far outside the range, unless near a track that is itself outside
                    # it (CollarFilter._at_track_place)
                    far = _far(i, z0, z1, rng, range_sigmas, range_margin, range_min) and \
                        not (dist - 3.0 * sigma <= range_margin
                             and _far(i, xi[0], xi[1], rng, range_sigmas, range_margin,
                                      range_min))
                    for c in range(n_cand[i] - 1, -1, -1):
                        if (_reach_ratio(i, c, s, z0, z1, r, cand_len, cand_t, cand_z,
                                         cand_r, max_speed, cruise_speed, sprint_s,
                                         gate_sigma) <= 1.0
                                and _chain_distance(i, c, z0, z1, cand_len, cand_z)
                                < innovation):
                            chain = _attach(i, c, s, z0, z1, r, cand_jump[i, c], n_cand,
                                            cand_jump, cand_len, cand_t, cand_z, cand_r,
                                            max_speed, cruise_speed, sprint_s, gate_sigma)
                            if far:
                                reason = RANGE
                            elif cand_jump[i, c]:
                                reason = SPEED
                            else:
                                reason = GATE
                            break
                    if chain < 0 and far:
                        reason = RANGE            # far outside the collar's range
                        chain = _attach(i, -1, s, z0, z1, r, True, n_cand, cand_jump,
                                        cand_len, cand_t, cand_z, cand_r, max_speed,
                                        cruise_speed, sprint_s, gate_sigma)
                    if chain < 0 and gate_d2 > gate:
                        reason = GATE
                        chain = _attach(i, -1, s, z0, z1, r, False, n_cand, cand_jump,
                                        cand_len, cand_t, cand_z, cand_r, max_speed,
                                        cruise_speed, sprint_s, gate_sigma)
                    if chain < 0 and walk_accel > 0.0:   # accepted: mixture update
                        if d2 > gate:
                            # taken by the walk component alone: a move it may undo
                            # (a place already held is kept, and this one beside it)
                            _keep_left(left, i, 0 if not math.isfinite(left[i, 0]) else 8,
                                       t, x, P, reacquire, 0.0)
                        _update(xp, Pp, z0, z1, r, W)
                        _update(xw, Pw, z0, z1, rw, W)
                        lw = (math.log(walk_prob) - 0.5 * math.log(detw) - 0.5 * d2w) - (
                            math.log1p(-walk_prob) - 0.5 * math.log(det) - 0.5 * d2)
                        ww = 1.0 / (1.0 + math.exp(-lw)) if lw > -700.0 else 0.0
                        _collapse(xp, Pp, xw, Pw, 1.0 - ww, ww, xi, Pi)
                        t[i] = s
                        n_cand[i] = 0
                        counters[i, C_ACC] += 1
                        code = ACCEPTED
                        _held(left, i)
                    elif chain < 0:           # accepted: filterpy predict + update
                        xi[:] = xp
                        Pi[:, :] = Pp
                        _update(xi, Pi, z0, z1, r, W)
                        t[i] = s
                        n_cand[i] = 0
                        counters[i, C_ACC] += 1
                        code = ACCEPTED
                        _held(left, i)
                if chain >= 0:
                    if reason == RANGE:
                        cand_jump[i, chain] = True  # a fix far outside the range: a jump
                    need = reacquire if cand_jump[i, chain] else confirm
                    if cand_len[i, chain] < need and \
                            _return_to_left(i, s, z0, z1, r, left, accel_std[i],
                                            velocity_tau[i], gate, t, x, P, xp, Pp, W):
                        n_cand[i] = 0             # back at the place it left: a burst
                        counters[i, C_ACC] += 1
                        counters[i, C_REINIT] += 1
                        code = REINITIALISED
                    elif cand_len[i, chain] < need:
                        code = reason
                        if reason == SPEED:
                            counters[i, C_SPEED] += 1
                        elif reason == RANGE:
                            counters[i, C_RANGE] += 1
                        else:
                            counters[i, C_GATE] += 1
                    else:
                        if cand_jump[i, chain]:
                            _forget_left(left, i)
                        else:                 # keep the place the track leaves
                            left[i, 8] = np.nan
                            _keep_left(left, i, 0, t, x, P, reacquire, 1.0)
                        _adopt(i, chain, t, x, P, ever, counters, n_cand, cand_len, cand_t,
                               cand_z, cand_r, accel_std[i], velocity_tau[i], v0, gate, W)
                        counters[i, C_REINIT] += 1
                        code = REINITIALISED
        out_code[m] = code
        out_d2[m] = d2
        out_seg[m] = counters[i, C_REINIT]
        if code == ACCEPTED or code == REINITIALISED:
            e = x[i, 0]
            nn = x[i, 1]
            rng[i, 0] += 1.0                # the state joins the collar's range
            rng[i, 1] += e
            rng[i, 2] += nn
            rng[i, 3] += e * e
            rng[i, 4] += e * nn
            rng[i, 5] += nn * nn
            out_x[m] = x[i]
            if keep_P:
                out_P[m] = P[i]
        else:
            out_x[m] = np.nan
            if keep_P:
                out_P[m] = np.nan


# -- the RTS smoother's backward pass (smoothing.rts_timeline) ----------------------------


@_jit
def rts_backward(link, x, Fx, P, Pp, J, xs, Ps):
    """The backward recursion of the Rauch-Tung-Striebel smoother (Rauch, Tung & Striebel
    1965; Särkkä 2013, *Bayesian Filtering and Smoothing*, Theorem 8.2), from the last
    state back, each step k where ``link[k]`` (state k + 1 follows state k in its
    segment)::

        x̂_k = x_k + J_k (x̂_{k+1} − F_k x_k),   P̂_k = P_k + J_k (P̂_{k+1} − P⁻_{k+1}) J_kᵀ

    ``Fx`` (K − 1, 4) = F_k x_k, ``Pp`` the priors P⁻_{k+1}, ``J`` the gains (K − 1, 4, 4);
    ``xs``, ``Ps`` (K, ·) hold the filtered states on entry (a segment's last state stays
    filtered) and the smoothed ones on return."""
    D = np.empty((4, 4))
    JD = np.empty((4, 4))
    for k in range(link.shape[0] - 1, -1, -1):
        if not link[k]:
            continue
        for i in range(4):
            acc = 0.0
            for j in range(4):
                acc += J[k, i, j] * (xs[k + 1, j] - Fx[k, j])
            xs[k, i] = x[k, i] + acc
        for i in range(4):
            for j in range(4):
                D[i, j] = Ps[k + 1, i, j] - Pp[k, i, j]
        for i in range(4):
            for j in range(4):
                acc = 0.0
                for m in range(4):
                    acc += J[k, i, m] * D[m, j]
                JD[i, j] = acc
        for i in range(4):
            for j in range(4):
                acc = 0.0
                for m in range(4):
                    acc += JD[i, m] * J[k, j, m]
                Ps[k, i, j] = P[k, i, j] + acc


# -- the streaming herd clock (herd_clock.BatchHerdClock) ---------------------------------


@_jit
def record_states(collar, stamp, x, P, motion, next_tick, count, rt, rx, rP, rm):
    """Append each accepted state (and the motion model (σ_a, τ_v) that carries it
    forward, ``motion`` (M, 2)) to its collar's ring, first dropping the states no longer
    needed (superseded by a later one at or before ``next_tick``); returns how many were
    stored (fewer: a ring is full of needed states and must grow)."""
    depth = rt.shape[1]
    for m in range(collar.shape[0]):
        i = collar[m]
        while count[i] >= 2 and rt[i, 1] <= next_tick:
            for k in range(count[i] - 1):
                rt[i, k] = rt[i, k + 1]
                rx[i, k] = rx[i, k + 1]
                rP[i, k] = rP[i, k + 1]
                rm[i, k] = rm[i, k + 1]
            count[i] -= 1
        if count[i] == depth:
            return m
        k = count[i]
        rt[i, k] = stamp[m]
        rx[i, k] = x[m]
        rP[i, k] = P[m]
        rm[i, k] = motion[m]
        count[i] = k + 1
    return collar.shape[0]


@_jit
def snapshot(tick, count, rt, rx, rP, rm, stale_after, x, P, stale, init):
    """Every collar's state at ``tick`` from its record (the herd clock's snapshot, compiled):
    the last record at or before the tick, predicted to it; NaN past ``stale_after``."""
    W = np.empty((4, 4, 4))
    for i in range(count.shape[0]):
        k = count[i] - 1
        while k >= 0 and rt[i, k] > tick:
            k -= 1
        if k < 0:
            x[i] = np.nan
            P[i] = np.nan
            stale[i] = True
            init[i] = False
            continue
        tau = tick - rt[i, k]
        _predict(rx[i, k], rP[i, k], tau, rm[i, k, 0], rm[i, k, 1], x[i], P[i], W)
        init[i] = True
        stale[i] = tau > stale_after
        if stale[i]:
            x[i] = np.nan


# -- the motion fit (motion_fit.innovation_loglik) ----------------------------------------


@_jit
def _fix_var(r, sm2):
    """A fix's variance in the likelihood (motion_refit.fix_variance): ``r`` where known
    (≥ 0), ``sm2 · (−r)`` for a fix scaled by its HDOP (``r`` = −HDOP²), ``sm2`` where
    unknown (NaN)."""
    if r >= 0.0:
        return r
    if r < 0.0:
        return sm2 * (-r)
    return sm2


@_jit
def _walk_steps(t, i, m, walk_accel, walk_tau, out):
    """The walk component's (f_pv, f_vv, q_pp, q_pv, q_vv) at each of collar i's first
    ``m`` intervals, into ``out[k]`` for the interval ending at fix k: they depend on the
    intervals alone, so a search computes them once per collar."""
    if walk_accel <= 0.0:
        return
    for k in range(1, m):
        f, gg, qpp, qpv, qvv = _motion(t[i, k] - t[i, k - 1], walk_accel, walk_tau)
        out[k, 0] = f
        out[k, 1] = gg
        out[k, 2] = qpp
        out[k, 3] = qpv
        out[k, 4] = qvv


@_jit
def _loglik_one(t, z, r, i, m, tv, D, sm2, walk, walk_prob, walk_r2, huber,
                distance, steps):
    """ℓ of collar i's first ``m`` fixes at one parameter point (see motion_loglik); with
    ``distance`` also the distance (m) from each fix k to the own model's prediction of
    it, written to ``steps[k]`` (see motion_distance; otherwise ``steps`` is not touched:
    an empty view, no allocation per evaluation);
    ``walk`` the walk component's steps (:func:`_walk_steps`), or an empty array for none.
    Per step one log per component (of the product of the axes' variances) and, for the
    mixture, one exp and one log1p (ℓ_k = max + log1p(e^{−|Δ|}), the weights from the same
    exponential)."""
    use_walk = walk.shape[0] > 0
    lg0 = math.log1p(-walk_prob) if use_walk else 0.0
    lw0 = math.log(walk_prob) if use_walk else 0.0
    log_two_pi = math.log(2.0 * math.pi)
    p = np.empty(2)
    v = np.empty(2)
    a = np.empty(2)
    b = np.empty(2)
    c = np.empty(2)
    comp = np.empty((2, 5, 2))          # component, (p, v, a, b, c), axis
    lc = np.empty(2)
    accel = math.sqrt(D) / tv
    r0 = _fix_var(r[i, 0], sm2)
    for ax in range(2):
        p[ax] = z[i, 0, ax]
        v[ax] = 0.0
        a[ax] = r0
        b[ax] = 0.0
        c[ax] = D / (2.0 * tv)
    ll = 0.0
    ncomp = 2 if use_walk else 1
    for k in range(1, m):
        dt = t[i, k] - t[i, k - 1]
        rk = _fix_var(r[i, k], sm2)
        for j in range(ncomp):
            if j == 0:
                f, gg, qpp, qpv, qvv = _motion(dt, accel, tv)
                extra = 0.0
            else:
                f = walk[k, 0]
                gg = walk[k, 1]
                qpp = walk[k, 2]
                qpv = walk[k, 3]
                qvv = walk[k, 4]
                extra = walk_r2
            nis = 0.0
            det = 1.0
            y2 = 0.0
            for ax in range(2):
                ap = a[ax] + 2.0 * f * b[ax] + f * f * c[ax] + qpp
                bp = gg * (b[ax] + f * c[ax]) + qpv
                cp = gg * gg * c[ax] + qvv
                S = ap + rk + extra
                kp = ap / S
                kv = bp / S
                pp = p[ax] + f * v[ax]
                y = z[i, k, ax] - pp
                nis += y * y / S
                y2 += y * y
                det *= S
                comp[j, 0, ax] = pp + kp * y
                comp[j, 1, ax] = gg * v[ax] + kv * y
                comp[j, 2, ax] = ap - kp * ap
                comp[j, 3, ax] = bp - kp * bp
                comp[j, 4, ax] = cp - kv * bp
            if distance and j == 0:
                steps[k] = math.sqrt(y2)
            if not use_walk and nis > huber:
                nis = 2.0 * math.sqrt(huber * nis) - huber
            lc[j] = (lg0 if j == 0 else lw0) - log_two_pi - 0.5 * math.log(det) - 0.5 * nis
        if not use_walk:
            ll += lc[0]
            for ax in range(2):
                p[ax] = comp[0, 0, ax]
                v[ax] = comp[0, 1, ax]
                a[ax] = comp[0, 2, ax]
                b[ax] = comp[0, 3, ax]
                c[ax] = comp[0, 4, ax]
            continue
        diff = lc[1] - lc[0]
        e = math.exp(-abs(diff))
        if diff > 0.0:
            lk = lc[1] + math.log1p(e)
            w1 = 1.0 / (1.0 + e)
        else:
            lk = lc[0] + math.log1p(e)
            w1 = e / (1.0 + e)
        ll += lk
        w0 = 1.0 - w1
        for ax in range(2):
            p0 = comp[0, 0, ax]
            p1 = comp[1, 0, ax]
            v0 = comp[0, 1, ax]
            v1 = comp[1, 1, ax]
            pn = w0 * p0 + w1 * p1
            vn = w0 * v0 + w1 * v1
            a[ax] = (w0 * (comp[0, 2, ax] + (p0 - pn) ** 2)
                     + w1 * (comp[1, 2, ax] + (p1 - pn) ** 2))
            b[ax] = (w0 * (comp[0, 3, ax] + (p0 - pn) * (v0 - vn))
                     + w1 * (comp[1, 3, ax] + (p1 - pn) * (v1 - vn)))
            c[ax] = (w0 * (comp[0, 4, ax] + (v0 - vn) ** 2)
                     + w1 * (comp[1, 4, ax] + (v1 - vn) ** 2))
            p[ax] = pn
            v[ax] = vn
    return ll


@_jit
def motion_loglik(t, z, r, n, velocity_tau, diffusion, position_var, walk_accel, walk_tau,
                  walk_prob, walk_r2, huber, out):
    """:func:`herd_ros.ingest.motion_fit.innovation_loglik` compiled: ``out[i, g]`` is
    collar i's log-likelihood at parameter point g (``walk_accel`` ≤ 0: no walk
    component; ``huber``: the χ²₂ level beyond which an innovation costs linearly, used
    without a walk component). The points of a collar are evaluated two at a time
    (:func:`_loglik_pair`: the same numbers as one at a time)."""
    walk = np.empty((t.shape[1] if walk_accel > 0.0 else 0, 5))
    G = velocity_tau.shape[1]
    for i in range(t.shape[0]):
        _walk_steps(t, i, n[i], walk_accel, walk_tau, walk)
        for g in range(0, G - 1, 2):
            out[i, g], out[i, g + 1] = _loglik_pair(
                t, z, r, i, n[i], velocity_tau[i, g], diffusion[i, g], position_var[i, g],
                walk, i, n[i], velocity_tau[i, g + 1], diffusion[i, g + 1],
                position_var[i, g + 1], walk, walk_prob, walk_r2, huber)
        if G % 2:
            out[i, G - 1] = _loglik_one(t, z, r, i, n[i], velocity_tau[i, G - 1],
                                        diffusion[i, G - 1], position_var[i, G - 1], walk,
                                        walk_prob, walk_r2, huber, False, out[i, :0])


@_jit
def motion_distance(t, z, r, n, velocity_tau, diffusion, position_var, walk_accel,
                    walk_tau, walk_prob, walk_r2, out):
    """:func:`herd_ros.ingest.motion_fit.one_step_distances` compiled: ``out[i, g, k]``
    is the distance (m) from collar i's fix k to where the filter at parameter point g
    predicted it (its own model's prediction, as the track says before the fix), the
    filter run as in :func:`motion_loglik`; NaN at its first fix and beyond its last."""
    walk = np.empty((t.shape[1] if walk_accel > 0.0 else 0, 5))
    out[:, :, :] = np.nan
    for i in range(t.shape[0]):
        _walk_steps(t, i, n[i], walk_accel, walk_tau, walk)
        for g in range(velocity_tau.shape[1]):
            _loglik_one(t, z, r, i, n[i], velocity_tau[i, g], diffusion[i, g],
                        position_var[i, g], walk, walk_prob, walk_r2, 0.0, True, out[i, g])


@_jit
def _nm_value(t, z, r, i, m, x, lo, hi, walk, walk_prob, walk_r2, huber):
    """−ℓ at log10 parameters x = (τ_v, σ_a, σ_m²), clipped to [lo, hi] (σ_a the
    acceleration std: well defined from the random walk to the constant velocity; the
    diffusion is D = σ_a² τ_v²)."""
    _nm_clip(x, lo, hi, i)
    tv, D, sm2 = _nm_params(x)
    return -_loglik_one(t, z, r, i, m, tv, D, sm2, walk, walk_prob, walk_r2, huber, False,
                        x[:0])


@_jit
def _nm_params(x):
    """(τ_v, D, σ_m²) at log10 parameters x = (τ_v, σ_a, σ_m²): D = σ_a² τ_v²."""
    tv = 10.0 ** x[0]
    sa = 10.0 ** x[1]
    return tv, sa * sa * tv * tv, 10.0 ** x[2]


@_jit
def _nm_clip(x, lo, hi, i):
    """x clipped to collar i's box [lo, hi], in place."""
    for d in range(3):
        x[d] = min(max(x[d], lo[i, d]), hi[i, d])


@_jit
def _lane_axis(p, v, a, b, c, f, gg, qpp, qpv, qvv, rk, extra, zk):
    """One axis of one component's predict and update in :func:`_loglik_one`, the same
    operations in the same order: (p, v, a, b, c after the update, y²/S, S)."""
    ap = a + 2.0 * f * b + f * f * c + qpp
    bp = gg * (b + f * c) + qpv
    cp = gg * gg * c + qvv
    S = ap + rk + extra
    kp = ap / S
    kv = bp / S
    pp = p + f * v
    y = zk - pp
    return pp + kp * y, gg * v + kv * y, ap - kp * ap, bp - kp * bp, cp - kv * bp, y * y / S, S


@_jit
def _lane_mix(w0, w1, p0, v0, a0, b0, c0, p1, v1, a1, b1, c1):
    """One axis of :func:`_loglik_one`'s collapse of the two components (moment matching)."""
    pn = w0 * p0 + w1 * p1
    vn = w0 * v0 + w1 * v1
    return (pn, vn, w0 * (a0 + (p0 - pn) ** 2) + w1 * (a1 + (p1 - pn) ** 2),
            w0 * (b0 + (p0 - pn) * (v0 - vn)) + w1 * (b1 + (p1 - pn) * (v1 - vn)),
            w0 * (c0 + (v0 - vn) ** 2) + w1 * (c1 + (v1 - vn) ** 2))


@_jit
def _lane_weights(l0, l1):
    """ℓ_k and the walk component's weight from the components' ℓ (:func:`_loglik_one`)."""
    diff = l1 - l0
    e = math.exp(-abs(diff))
    if diff > 0.0:
        return l1 + math.log1p(e), 1.0 / (1.0 + e)
    return l0 + math.log1p(e), e / (1.0 + e)


@_jit
def _loglik_pair(t, z, r, i, mi, tvi, Di, smi, walk_i, j, mj, tvj, Dj, smj, walk_j,
                 walk_prob, walk_r2, huber):
    """(ℓ_i, ℓ_j): :func:`_loglik_one` of two evaluations at once (collar i's first ``mi``
    fixes at (τ_v, D, σ_m²) = (tvi, Di, smi), collar j's likewise), to the last bit what
    two calls give. Each step of one recursion waits on its exp and logs; two independent
    ones written side by side, stage by stage, keep the core busy: 1.35 × the evaluations
    per second with the walk component, 1.25 × without, on a core of its own (where two
    threads share one core, as this machine's two virtual CPUs do under load, the core is
    busy anyway and the gain is gone). ``walk_i``, ``walk_j``: each collar's walk steps
    (:func:`_walk_steps`), both empty for no walk component. Past the shorter collar's
    last fix the longer one goes on alone (:func:`_lane_rest`)."""
    use_walk = walk_i.shape[0] > 0
    lg0 = math.log1p(-walk_prob) if use_walk else 0.0
    lw0 = math.log(walk_prob) if use_walk else 0.0
    log_two_pi = math.log(2.0 * math.pi)
    Ai = math.sqrt(Di) / tvi
    Aj = math.sqrt(Dj) / tvj
    r0 = _fix_var(r[i, 0], smi)
    ipx, ipy, ivx, ivy, iax, iay, ibx, iby = z[i, 0, 0], z[i, 0, 1], 0.0, 0.0, r0, r0, 0.0, 0.0
    icx = Di / (2.0 * tvi)
    icy = Di / (2.0 * tvi)
    r0 = _fix_var(r[j, 0], smj)
    jpx, jpy, jvx, jvy, jax, jay, jbx, jby = z[j, 0, 0], z[j, 0, 1], 0.0, 0.0, r0, r0, 0.0, 0.0
    jcx = Dj / (2.0 * tvj)
    jcy = Dj / (2.0 * tvj)
    ll_i = 0.0
    ll_j = 0.0
    both = min(mi, mj)
    for k in range(1, both):
        rki = _fix_var(r[i, k], smi)
        rkj = _fix_var(r[j, k], smj)
        fi, gi, qppi, qpvi, qvvi = _motion(t[i, k] - t[i, k - 1], Ai, tvi)
        fj, gj, qppj, qpvj, qvvj = _motion(t[j, k] - t[j, k - 1], Aj, tvj)
        i0x = _lane_axis(ipx, ivx, iax, ibx, icx, fi, gi, qppi, qpvi, qvvi, rki, 0.0, z[i, k, 0])
        j0x = _lane_axis(jpx, jvx, jax, jbx, jcx, fj, gj, qppj, qpvj, qvvj, rkj, 0.0, z[j, k, 0])
        i0y = _lane_axis(ipy, ivy, iay, iby, icy, fi, gi, qppi, qpvi, qvvi, rki, 0.0, z[i, k, 1])
        j0y = _lane_axis(jpy, jvy, jay, jby, jcy, fj, gj, qppj, qpvj, qvvj, rkj, 0.0, z[j, k, 1])
        nis_i = 0.0 + i0x[5] + i0y[5]
        nis_j = 0.0 + j0x[5] + j0y[5]
        if not use_walk:
            if nis_i > huber:
                nis_i = 2.0 * math.sqrt(huber * nis_i) - huber
            if nis_j > huber:
                nis_j = 2.0 * math.sqrt(huber * nis_j) - huber
        li0 = lg0 - log_two_pi - 0.5 * math.log(1.0 * i0x[6] * i0y[6]) - 0.5 * nis_i
        lj0 = lg0 - log_two_pi - 0.5 * math.log(1.0 * j0x[6] * j0y[6]) - 0.5 * nis_j
        if not use_walk:
            ll_i += li0
            ll_j += lj0
            ipx, ivx, iax, ibx, icx = i0x[0], i0x[1], i0x[2], i0x[3], i0x[4]
            ipy, ivy, iay, iby, icy = i0y[0], i0y[1], i0y[2], i0y[3], i0y[4]
            jpx, jvx, jax, jbx, jcx = j0x[0], j0x[1], j0x[2], j0x[3], j0x[4]
            jpy, jvy, jay, jby, jcy = j0y[0], j0y[1], j0y[2], j0y[3], j0y[4]
            continue
        wi = walk_i[k]
        wj = walk_j[k]
        i1x = _lane_axis(ipx, ivx, iax, ibx, icx, wi[0], wi[1], wi[2], wi[3], wi[4], rki,
                         walk_r2, z[i, k, 0])
        j1x = _lane_axis(jpx, jvx, jax, jbx, jcx, wj[0], wj[1], wj[2], wj[3], wj[4], rkj,
                         walk_r2, z[j, k, 0])
        i1y = _lane_axis(ipy, ivy, iay, iby, icy, wi[0], wi[1], wi[2], wi[3], wi[4], rki,
                         walk_r2, z[i, k, 1])
        j1y = _lane_axis(jpy, jvy, jay, jby, jcy, wj[0], wj[1], wj[2], wj[3], wj[4], rkj,
                         walk_r2, z[j, k, 1])
        li1 = (lw0 - log_two_pi - 0.5 * math.log(1.0 * i1x[6] * i1y[6])
               - 0.5 * (0.0 + i1x[5] + i1y[5]))
        lj1 = (lw0 - log_two_pi - 0.5 * math.log(1.0 * j1x[6] * j1y[6])
               - 0.5 * (0.0 + j1x[5] + j1y[5]))
        lki, w1i = _lane_weights(li0, li1)
        lkj, w1j = _lane_weights(lj0, lj1)
        ll_i += lki
        ll_j += lkj
        w0i = 1.0 - w1i
        w0j = 1.0 - w1j
        ipx, ivx, iax, ibx, icx = _lane_mix(w0i, w1i, i0x[0], i0x[1], i0x[2], i0x[3], i0x[4],
                                            i1x[0], i1x[1], i1x[2], i1x[3], i1x[4])
        jpx, jvx, jax, jbx, jcx = _lane_mix(w0j, w1j, j0x[0], j0x[1], j0x[2], j0x[3], j0x[4],
                                            j1x[0], j1x[1], j1x[2], j1x[3], j1x[4])
        ipy, ivy, iay, iby, icy = _lane_mix(w0i, w1i, i0y[0], i0y[1], i0y[2], i0y[3], i0y[4],
                                            i1y[0], i1y[1], i1y[2], i1y[3], i1y[4])
        jpy, jvy, jay, jby, jcy = _lane_mix(w0j, w1j, j0y[0], j0y[1], j0y[2], j0y[3], j0y[4],
                                            j1y[0], j1y[1], j1y[2], j1y[3], j1y[4])
    if mi > both:
        ll_i = _lane_rest(t, z, r, i, max(both, 1), mi, tvi, Ai, smi, walk_i, use_walk, lg0,
                          lw0, log_two_pi, walk_r2, huber, ll_i,
                          (ipx, ivx, iax, ibx, icx, ipy, ivy, iay, iby, icy))
    if mj > both:
        ll_j = _lane_rest(t, z, r, j, max(both, 1), mj, tvj, Aj, smj, walk_j, use_walk, lg0,
                          lw0, log_two_pi, walk_r2, huber, ll_j,
                          (jpx, jvx, jax, jbx, jcx, jpy, jvy, jay, jby, jcy))
    return ll_i, ll_j


@_jit
def _lane_rest(t, z, r, c, k0, m, tv, acc, sm2, walk, use_walk, lg0, lw0, log_two_pi,
               walk_r2, huber, ll, state):
    """Collar c's steps k0 … m − 1 of :func:`_loglik_one` on their own, from ``state``
    (p, v, a, b, c of the east axis, then of the north) and the ℓ so far: the longer
    collar's rest in :func:`_loglik_pair`, the same operations as there."""
    px, vx, ax, bx, cx, py, vy, ay, by, cy = state
    for k in range(k0, m):
        rk = _fix_var(r[c, k], sm2)
        f, gg, qpp, qpv, qvv = _motion(t[c, k] - t[c, k - 1], acc, tv)
        gx = _lane_axis(px, vx, ax, bx, cx, f, gg, qpp, qpv, qvv, rk, 0.0, z[c, k, 0])
        gy = _lane_axis(py, vy, ay, by, cy, f, gg, qpp, qpv, qvv, rk, 0.0, z[c, k, 1])
        nis = 0.0 + gx[5] + gy[5]
        if not use_walk and nis > huber:
            nis = 2.0 * math.sqrt(huber * nis) - huber
        l0 = lg0 - log_two_pi - 0.5 * math.log(1.0 * gx[6] * gy[6]) - 0.5 * nis
        if not use_walk:
            ll += l0
            px, vx, ax, bx, cx = gx[0], gx[1], gx[2], gx[3], gx[4]
            py, vy, ay, by, cy = gy[0], gy[1], gy[2], gy[3], gy[4]
            continue
        w = walk[k]
        hx = _lane_axis(px, vx, ax, bx, cx, w[0], w[1], w[2], w[3], w[4], rk, walk_r2,
                        z[c, k, 0])
        hy = _lane_axis(py, vy, ay, by, cy, w[0], w[1], w[2], w[3], w[4], rk, walk_r2,
                        z[c, k, 1])
        l1 = (lw0 - log_two_pi - 0.5 * math.log(1.0 * hx[6] * hy[6])
              - 0.5 * (0.0 + hx[5] + hy[5]))
        lk, w1 = _lane_weights(l0, l1)
        ll += lk
        w0 = 1.0 - w1
        px, vx, ax, bx, cx = _lane_mix(w0, w1, gx[0], gx[1], gx[2], gx[3], gx[4], hx[0],
                                       hx[1], hx[2], hx[3], hx[4])
        py, vy, ay, by, cy = _lane_mix(w0, w1, gy[0], gy[1], gy[2], gy[3], gy[4], hy[0],
                                       hy[1], hy[2], hy[3], hy[4])
    return ll


#: the phases of a lane of :func:`motion_nelder_mead`, by the point it waits on: none
#: (idle), a vertex of the first simplex, the reflection, the expansion, the
#: contraction, a vertex of a shrink
_NM_IDLE, _NM_INIT, _NM_REFLECT, _NM_EXPAND, _NM_CONTRACT, _NM_SHRINK = 0, 1, 2, 3, 4, 5


@_jit
def _nm_point(phase, ln, jv, S, XR, XE, XK):
    """The point lane ln waits on: a vertex (initial simplex, shrink) or a trial point."""
    if phase[ln] == _NM_INIT or phase[ln] == _NM_SHRINK:
        return S[ln, jv[ln]]
    if phase[ln] == _NM_REFLECT:
        return XR[ln]
    if phase[ln] == _NM_EXPAND:
        return XE[ln]
    return XK[ln]


@_jit
def _nm_top(ln, i, S, F, XC, XR, nfree, evals, max_evals, ftol, phase, out_x, out_ll):
    """The head of Nelder-Mead's loop for lane ln (collar i): done (its best vertex
    written, the lane idle) once its budget is spent or its simplex's values agree within
    ``ftol``; else the vertices sorted, best first, and the reflection of the worst is
    the point it waits on."""
    nf = nfree[ln]
    done = evals[ln] >= max_evals[i]
    if not done:
        for j in range(1, nf + 1):
            k = j
            while k > 0 and F[ln, k] < F[ln, k - 1]:
                for d in range(3):
                    tmp = S[ln, k, d]
                    S[ln, k, d] = S[ln, k - 1, d]
                    S[ln, k - 1, d] = tmp
                tmp = F[ln, k]
                F[ln, k] = F[ln, k - 1]
                F[ln, k - 1] = tmp
                k -= 1
        done = F[ln, nf] - F[ln, 0] < ftol
    if done:
        best = 0
        for j in range(1, nf + 1):
            if F[ln, j] < F[ln, best]:
                best = j
        out_x[i, :] = S[ln, best]
        out_ll[i] = -F[ln, best]
        phase[ln] = _NM_IDLE
        return
    for d in range(3):
        s_ = 0.0
        for j in range(nf):
            s_ += S[ln, j, d]
        XC[ln, d] = s_ / nf
    for d in range(3):
        XR[ln, d] = XC[ln, d] + (XC[ln, d] - S[ln, nf, d])
    phase[ln] = _NM_REFLECT


@_jit
def _nm_advance(ln, i, value, S, F, XC, XR, XE, XK, FR, nfree, evals, jv, max_evals, ftol,
                phase, out_x, out_ll):
    """Lane ln (collar i) takes the value (−ℓ) of the point it waited on and moves on to
    the next point, Nelder & Mead's rules as the one-collar loop had them."""
    nf = nfree[ln]
    p = phase[ln]
    if p == _NM_INIT:
        F[ln, jv[ln]] = value
        jv[ln] += 1
        if jv[ln] <= nf:
            return
        evals[ln] = nf + 1
    elif p == _NM_REFLECT:
        evals[ln] += 1
        FR[ln] = value
        if value < F[ln, 0]:
            for d in range(3):
                XE[ln, d] = XC[ln, d] + 2.0 * (XC[ln, d] - S[ln, nf, d])
            phase[ln] = _NM_EXPAND
            return
        if value < F[ln, nf - 1]:
            S[ln, nf, :] = XR[ln]
            F[ln, nf] = value
        else:
            outside = value < F[ln, nf]
            for d in range(3):
                base = XR[ln, d] if outside else S[ln, nf, d]
                XK[ln, d] = XC[ln, d] + 0.5 * (base - XC[ln, d])
            phase[ln] = _NM_CONTRACT
            return
    elif p == _NM_EXPAND:
        evals[ln] += 1
        if value < FR[ln]:
            S[ln, nf, :] = XE[ln]
            F[ln, nf] = value
        else:
            S[ln, nf, :] = XR[ln]
            F[ln, nf] = FR[ln]
    elif p == _NM_CONTRACT:
        evals[ln] += 1
        if value < min(FR[ln], F[ln, nf]):
            S[ln, nf, :] = XK[ln]
            F[ln, nf] = value
        else:
            for j in range(1, nf + 1):          # shrink towards the best
                for d in range(3):
                    S[ln, j, d] = S[ln, 0, d] + 0.5 * (S[ln, j, d] - S[ln, 0, d])
            jv[ln] = 1
            phase[ln] = _NM_SHRINK
            return
    else:                                       # shrink
        F[ln, jv[ln]] = value
        evals[ln] += 1
        jv[ln] += 1
        if jv[ln] <= nf:
            return
    _nm_top(ln, i, S, F, XC, XR, nfree, evals, max_evals, ftol, phase, out_x, out_ll)


@_jit
def motion_nelder_mead(t, z, r, n, x0, lo, hi, step, walk_accel, walk_tau, walk_prob,
                       walk_r2,
                       huber, max_evals, ftol, out_x, out_ll):
    """Maximise each collar's ℓ over log10 (τ_v, σ_a, σ_m²) by Nelder & Mead (1965) from
    ``x0`` (N, 3) with initial steps ``step`` (N, 3) (a coordinate with step 0 is held),
    within [lo, hi] (N, 3); stops when the simplex's values agree within ``ftol`` or
    after ``max_evals[i]`` evaluations. Writes the optimum to ``out_x`` (N, 3), ℓ to
    ``out_ll`` (N,).

    Two collars are searched side by side (two *lanes*, each a state machine over its
    simplex: :func:`_nm_advance`), so that their likelihood evaluations run as pairs
    (:func:`_loglik_pair`); each collar's search, evaluation by evaluation, is what it
    would be alone, to the last bit (``test_motion_fit.py``). On one thread, 200 collars'
    200-fix windows from one start (120 evaluations at most) take 0.125 s against 0.166 s
    one collar after another."""
    L = 2
    W = t.shape[1] if walk_accel > 0.0 else 0
    walk = np.empty((L, W, 5))
    S = np.empty((L, 4, 3))
    F = np.empty((L, 4))
    XC = np.empty((L, 3))
    XR = np.empty((L, 3))
    XE = np.empty((L, 3))
    XK = np.empty((L, 3))
    FR = np.empty(L)
    nfree = np.zeros(L, np.int64)
    evals = np.zeros(L, np.int64)
    jv = np.zeros(L, np.int64)
    phase = np.zeros(L, np.int64)
    col = np.zeros(L, np.int64)
    nxt = 0
    N = t.shape[0]
    while True:
        for ln in range(L):                      # an idle lane takes the next collar
            while phase[ln] == _NM_IDLE and nxt < N:
                i = nxt
                nxt += 1
                _walk_steps(t, i, n[i], walk_accel, walk_tau, walk[ln])
                nf = 0
                for d in range(3):
                    if step[i, d] != 0.0:
                        nf += 1
                if nf == 0:
                    out_x[i, :] = x0[i]
                    out_ll[i] = -_nm_value(t, z, r, i, n[i], out_x[i], lo, hi, walk[ln],
                                           walk_prob, walk_r2, huber)
                    continue
                k = 0
                for j in range(nf + 1):
                    for d in range(3):
                        S[ln, j, d] = x0[i, d]
                for d in range(3):
                    if step[i, d] != 0.0:
                        k += 1
                        S[ln, k, d] += step[i, d]
                col[ln] = i
                nfree[ln] = nf
                evals[ln] = 0
                jv[ln] = 0
                phase[ln] = _NM_INIT
        a = phase[0] != _NM_IDLE
        b = phase[1] != _NM_IDLE
        if not (a or b):
            break
        ia = col[0]
        ib = col[1]
        if a:
            xa = _nm_point(phase, 0, jv, S, XR, XE, XK)
            _nm_clip(xa, lo, hi, ia)
        if b:
            xb = _nm_point(phase, 1, jv, S, XR, XE, XK)
            _nm_clip(xb, lo, hi, ib)
        if a and b:
            tva, Da, sma = _nm_params(xa)
            tvb, Db, smb = _nm_params(xb)
            la, lb = _loglik_pair(t, z, r, ia, n[ia], tva, Da, sma, walk[0], ib, n[ib], tvb,
                                  Db, smb, walk[1], walk_prob, walk_r2, huber)
            va = -la
            vb = -lb
        elif a:
            va = _nm_value(t, z, r, ia, n[ia], xa, lo, hi, walk[0], walk_prob, walk_r2,
                           huber)
        else:
            vb = _nm_value(t, z, r, ib, n[ib], xb, lo, hi, walk[1], walk_prob, walk_r2,
                           huber)
        if a:
            _nm_advance(0, ia, va, S, F, XC, XR, XE, XK, FR, nfree, evals, jv, max_evals,
                        ftol, phase, out_x, out_ll)
        if b:
            _nm_advance(1, ib, vb, S, F, XC, XR, XE, XK, FR, nfree, evals, jv, max_evals,
                        ftol, phase, out_x, out_ll)
