"""Every collar's Kalman filter at once: array state, one compiled pass over a batch of fixes.

:class:`~herd_ros.ingest.collar_filter.CollarFilter` (one filterpy ``KalmanFilter`` per
collar, one Python call per fix) is the reference implementation: readable, close to the
textbook, and what the tests compare against. It costs ~200 µs of interpreter per fix
(argument checks, small-array allocation, ``np.linalg`` dispatch on 2 × 2 matrices), so
360 000 fixes take over a minute, and a node serving 1 000 collars at 1 Hz spends most of a
core on it. This module is the hot path of both ``herd-ros ingest`` and the ``gps_ingest``
node: the same filter, the same gates and the same reacquisition, with

* the state of N collars in arrays: ``t`` (N,), ``x`` (N, 4), ``P`` (N, 4, 4), counters
  (N, 8) and the open candidate chains (N, 4 chains, L fixes);
* one compiled loop (numba) over a batch of fixes in arrival order. The loop cannot be
  vectorised across fixes (each fix of a collar starts from the state the previous one
  left) and branches per fix (checks, chains, adoption); every step in it is the 2 × 2 /
  4 × 4 algebra of the reference written out in scalars;
* the measurement covariances ``R`` of the whole batch computed beforehand, vectorised, in
  closed form (:func:`measurement_covariances`).

The equations are those of :mod:`herd_ros.ingest.collar_filter` (its module docstring cites
them): the motion model of :func:`~herd_ros.ingest.collar_filter.transition` /
:func:`~herd_ros.ingest.collar_filter.process_noise`, filterpy's predict
(``P⁻ = F P Fᵀ + Q``) and Joseph-form update (``P = (I − KH) P⁻ (I − KH)ᵀ + K R Kᵀ``), the
checks no_fix → nan → time → speed envelope → chain association → Mahalanobis gate, the
candidate chains and their confirmation. Only the rounding differs (2 × 2 inverses and
eigenvalues in closed form instead of LAPACK): ~1e-12 m after thousands of fixes;
``test/test_collar_bank.py`` checks outcomes and states against the reference to 1e-9 m on
herds with every fault of the real-collar generator.

``numba`` compiles the loop once and caches it on disk (``cache=True``, as the RLS kernel:
``__pycache__`` beside this file when writable, else numba's cache directory).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from herd_ros.ingest.collar_filter import COUNTERS, STATUS_NO_FIX, FilterParams

try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is an install requirement
    njit = None

AVAILABLE = njit is not None

#: outcome codes of :meth:`CollarBank.process`, indices into this tuple (the reasons of
#: :class:`~herd_ros.ingest.collar_filter.FixResult`)
OUTCOMES = ('accepted', 'reinitialised', 'no_fix', 'nan', 'time', 'gate', 'speed',
            'unconfirmed')
ACCEPTED, REINITIALISED, NO_FIX, NAN, TIME, GATE, SPEED, UNCONFIRMED = range(8)
#: open candidate chains per collar (CollarFilter.MAX_CANDIDATES)
MAX_CANDIDATES = 4

# counter columns, in COUNTERS order
_C_ACC, _C_NO_FIX, _C_NAN, _C_TIME, _C_GATE, _C_SPEED, _C_UNCONF, _C_REINIT = range(8)
assert COUNTERS == ('accepted', 'rejected_no_fix', 'rejected_nan', 'rejected_time',
                    'rejected_gate', 'rejected_speed', 'rejected_unconfirmed',
                    'reinitialised')


def measurement_covariances(cov_type, cov9, default_position_std: float,
                            position_std_floor: float) -> np.ndarray:
    """``R`` (M, 2, 2) of M fixes from their NavSatFix covariance type (M,) and
    ``position_covariance`` (M, 9): the rules of
    :func:`~herd_ros.ingest.collar_filter.measurement_covariance`, vectorised.

    The floor ``R = V max(Λ, floor²) Vᵀ`` in closed form: with eigenvalues λ₁ ≤ λ₂ and
    the projector ``Π₁ = (A − λ₂ I)/(λ₁ − λ₂)`` on the first eigenvector,
    ``R = max(λ₂, f²) I + (max(λ₁, f²) − max(λ₂, f²)) Π₁``; ``R = A`` when λ₁ ≥ f².
    """
    cov_type = np.ascontiguousarray(cov_type, dtype=np.int64).reshape(-1)
    c = np.ascontiguousarray(cov9, dtype=float).reshape(len(cov_type), 9)
    r = np.empty((len(cov_type), 2, 2))
    _covariances(cov_type, c, float(default_position_std) ** 2,
                 float(position_std_floor) ** 2, r)
    return r


def predict_states(x, P, tau, accel_std: float, velocity_tau: float = 0.0):
    """:func:`~herd_ros.ingest.collar_filter.predict_state` for M states at once, compiled:
    ``x`` (M, 4), ``P`` (M, 4, 4), ``tau`` (M,) -> (x⁻ (M, 4), P⁻ (M, 4, 4)). The herd
    clock carries every collar's state to a tick with it."""
    x = np.ascontiguousarray(x, dtype=float).reshape(-1, 4)
    P = np.ascontiguousarray(P, dtype=float).reshape(-1, 4, 4)
    tau = np.ascontiguousarray(np.broadcast_to(np.asarray(tau, dtype=float), (len(x),)))
    xo = np.empty_like(x)
    Po = np.empty_like(P)
    _predict_many(x, P, tau, float(accel_std), float(velocity_tau), xo, Po)
    return xo, Po


@dataclass
class FixBatch:
    """What :meth:`CollarBank.process` did with a batch of M fixes (in the batch's order).

    Attributes:
        outcome: (M,) int8 codes, names in :data:`OUTCOMES`.
        mahalanobis2: (M,) squared Mahalanobis distance (NaN where not computed).
        x: (M, 4) the collar's state after the fix where it was accepted (else NaN).
        P: (M, 4, 4) its covariance (absent, shape (0, 4, 4), if not asked for).
        segment: (M,) the collar's reinitialisation count after the fix.
    """

    outcome: np.ndarray
    mahalanobis2: np.ndarray
    x: np.ndarray
    P: np.ndarray
    segment: np.ndarray

    @property
    def accepted(self) -> np.ndarray:
        """(M,) the fix updated its collar's state."""
        return self.outcome <= REINITIALISED


class CollarBank:
    """The filters of ``n`` collars (indices 0..n-1), driven by batches of fixes.

    Usage::

        bank = CollarBank(len(agents), FilterParams(...))
        batch = bank.process(collar, stamp, east, north, status, R)
        batch.outcome, batch.x                  # per fix
        bank.t, bank.x, bank.P, bank.counters   # per collar, after the batch

    ``params`` may be replaced between batches (the node's live parameters).
    """

    def __init__(self, n: int, params: FilterParams | None = None):
        if not AVAILABLE:  # pragma: no cover
            raise RuntimeError('CollarBank needs numba; use CollarFilter instead')
        self.params = params if params is not None else FilterParams()
        n = int(n)
        L = max(int(self.params.confirm_fixes), int(self.params.reacquire_fixes),
                int(self.params.confirm_fixes_lost))
        self.n = n
        self.t = np.full(n, np.nan)
        self.x = np.zeros((n, 4))
        self.P = np.zeros((n, 4, 4))
        self.ever = np.zeros(n, np.bool_)
        self.last_position_fix = np.full(n, -np.inf)
        self.last_report = np.full(n, np.nan)
        self.counters = np.zeros((n, len(COUNTERS)), np.int64)
        self.n_candidates = np.zeros(n, np.int64)
        self.cand_jump = np.zeros((n, MAX_CANDIDATES), np.bool_)
        self.cand_len = np.zeros((n, MAX_CANDIDATES), np.int64)
        self.cand_t = np.zeros((n, MAX_CANDIDATES, L))
        self.cand_z = np.zeros((n, MAX_CANDIDATES, L, 2))
        self.cand_r = np.zeros((n, MAX_CANDIDATES, L, 2, 2))

    @staticmethod
    def warm_up():
        """Load the compiled loop (numba's cache: ~0.3 s the first time in a process) so
        that the first fixes of a live node do not wait for it."""
        bank = CollarBank(1)
        bank.process(np.zeros(1, np.int64), np.zeros(1), np.zeros(1), np.zeros(1),
                     np.zeros(1, np.int64),
                     bank.measurement_covariances(np.zeros(1, np.int64), np.zeros((1, 9))))

    @property
    def initialised(self) -> np.ndarray:
        """(n,) the collar has a track."""
        return np.isfinite(self.t)

    def counter_dict(self, i: int) -> dict:
        """Counters of collar ``i`` keyed by :data:`COUNTERS`."""
        return dict(zip(COUNTERS, (int(v) for v in self.counters[i])))

    def is_stale(self, t: float) -> np.ndarray:
        """(n,) no accepted fix for more than ``stale_after`` seconds before ``t`` (or
        never), as :meth:`CollarFilter.is_stale`."""
        with np.errstate(invalid='ignore'):
            return ~(float(t) - self.t <= self.params.stale_after)

    def measurement_covariances(self, cov_type, cov9) -> np.ndarray:
        """``R`` (M, 2, 2) for a batch, with this bank's default std and floor."""
        return measurement_covariances(cov_type, cov9, self.params.default_position_std,
                                       self.params.position_std_floor)

    def process(self, collar, stamp, east, north, status, R, *, keep_covariance=True,
                out: FixBatch | None = None) -> FixBatch:
        """Process M fixes in the given order (each collar's fixes in arrival order).

        Args:
            collar: (M,) collar indices.
            stamp: (M,) data time (s).
            east, north: (M,) ENU position (m) about the datum (NaN for no position).
            status: (M,) NavSatStatus.status.
            R: (M, 2, 2) measurement covariances (:meth:`measurement_covariances`).
            keep_covariance: also return the state covariance after each accepted fix.
            out: arrays of M rows to write the results into (views of larger arrays).
        """
        collar = np.ascontiguousarray(collar, dtype=np.int64)
        m = len(collar)
        if m and (collar.min() < 0 or collar.max() >= self.n):
            raise IndexError(f'collar index out of range 0..{self.n - 1}')
        stamp = np.ascontiguousarray(stamp, dtype=float)
        east = np.ascontiguousarray(east, dtype=float)
        north = np.ascontiguousarray(north, dtype=float)
        status = np.ascontiguousarray(status, dtype=np.int64)
        R = np.ascontiguousarray(R, dtype=float).reshape(m, 2, 2)
        if out is None:
            out = FixBatch(np.empty(m, np.int8), np.empty(m), np.empty((m, 4)),
                           np.empty((m if keep_covariance else 0, 4, 4)),
                           np.empty(m, np.int64))
        out_code, out_d2, out_x, out_P, out_seg = (out.outcome, out.mahalanobis2, out.x,
                                                   out.P, out.segment)
        p = self.params
        gate = p.gate_threshold
        _process_batch(collar, stamp, east, north, status, R,
                       self.t, self.x, self.P, self.ever, self.last_position_fix,
                       self.last_report, self.counters, self.n_candidates, self.cand_jump,
                       self.cand_len, self.cand_t, self.cand_z, self.cand_r,
                       float(p.accel_std), float(p.velocity_tau), float(p.max_speed),
                       float(p.cruise_speed), float(p.sprint_s), gate, math.sqrt(gate),
                       float(p.initial_velocity_std or p.max_speed),
                       int(p.confirm_fixes), int(p.reacquire_fixes),
                       int(p.confirm_fixes_lost), float(p.reinit_after_gap),
                       out_code, out_d2, out_x, out_P, out_seg)
        return out


# -- the compiled loop ----------------------------------------------------------------------
def _jit(fn):
    return njit(cache=True, nogil=True)(fn) if AVAILABLE else fn


@_jit
def _covariances(cov_type, c, d2, f2, r):
    """The loop of :func:`measurement_covariances`."""
    for m in range(cov_type.shape[0]):
        t = cov_type[m]
        known = (t != 0 and math.isfinite(c[m, 0]) and math.isfinite(c[m, 1])
                 and math.isfinite(c[m, 3]) and math.isfinite(c[m, 4]))
        if known:
            a = c[m, 0]
            cc = c[m, 4]
            b = 0.0 if t == 2 else 0.5 * (c[m, 1] + c[m, 3])
        else:
            a = d2
            cc = d2
            b = 0.0
        mid = 0.5 * (a + cc)
        d = math.hypot(0.5 * (a - cc), b)
        l1 = mid - d
        l2 = mid + d
        if l1 >= f2:
            r[m, 0, 0] = a
            r[m, 1, 1] = cc
            r[m, 0, 1] = r[m, 1, 0] = b
            continue
        L1 = max(l1, f2)
        L2 = max(l2, f2)
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
        a = -math.expm1(-beta * tau)
        b = -math.expm1(-2.0 * beta * tau)
        f_pv = a / beta
        f_vv = math.exp(-beta * tau)
        vv = var / (2.0 * beta) * b
        pv = var / (2.0 * beta ** 2) * a ** 2
        pp = var / beta ** 2 * (tau - 2.0 * a / beta + b / (2.0 * beta))
        if pp < 0.0:
            pp = 0.0
        return f_pv, f_vv, pp, pv, vv
    return tau, 1.0, var * tau ** 4 / 4.0, var * tau ** 3 / 2.0, var * tau ** 2


@_jit
def _sandwich(A, P, out):
    """out = A P Aᵀ (4 × 4), summed in the order of the matrix products."""
    AP = np.zeros((4, 4))
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
def _predict(x, P, tau, accel_std, velocity_tau, xo, Po):
    """xo = F x, Po = F P Fᵀ + Q (filterpy's predict)."""
    f_pv, f_vv, pp, pv, vv = _motion(tau, accel_std, velocity_tau)
    F = np.zeros((4, 4))
    F[0, 0] = F[1, 1] = 1.0
    F[0, 2] = F[1, 3] = f_pv
    F[2, 2] = F[3, 3] = f_vv
    for i in range(4):
        s = 0.0
        for j in range(4):
            s += F[i, j] * x[j]
        xo[i] = s
    _sandwich(F, P, Po)
    for i in range(2):
        Po[i, i] += pp
        Po[i, i + 2] += pv
        Po[i + 2, i] += pv
        Po[i + 2, i + 2] += vv


@_jit
def _predict_many(x, P, tau, accel_std, velocity_tau, xo, Po):
    for m in range(x.shape[0]):
        _predict(x[m], P[m], tau[m], accel_std, velocity_tau, xo[m], Po[m])


@_jit
def _update(x, P, z0, z1, R):
    """filterpy's update with H = [I 0]: K = P Hᵀ S⁻¹, x += K y,
    P = (I − KH) P (I − KH)ᵀ + K R Kᵀ (Joseph form), in place."""
    y0 = z0 - x[0]
    y1 = z1 - x[1]
    s00 = P[0, 0] + R[0, 0]
    s01 = P[0, 1] + R[0, 1]
    s10 = P[1, 0] + R[1, 0]
    s11 = P[1, 1] + R[1, 1]
    det = s00 * s11 - s01 * s10
    i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
    K = np.empty((4, 2))
    for i in range(4):
        K[i, 0] = P[i, 0] * i00 + P[i, 1] * i10
        K[i, 1] = P[i, 0] * i01 + P[i, 1] * i11
    for i in range(4):
        x[i] += K[i, 0] * y0 + K[i, 1] * y1
    A = np.zeros((4, 4))          # I − K H
    for i in range(4):
        A[i, i] = 1.0
        A[i, 0] -= K[i, 0]
        A[i, 1] -= K[i, 1]
    KR = np.empty((4, 2))
    for i in range(4):
        KR[i, 0] = K[i, 0] * R[0, 0] + K[i, 1] * R[1, 0]
        KR[i, 1] = K[i, 0] * R[0, 1] + K[i, 1] * R[1, 1]
    _sandwich(A, P, P)
    for i in range(4):
        for j in range(4):
            P[i, j] += KR[i, 0] * K[j, 0] + KR[i, 1] * K[j, 1]


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
def _attach(i, chain, stamp, z0, z1, r, jump, n_cand, cand_jump, cand_len, cand_t, cand_z,
            cand_r, max_speed, cruise_speed, sprint_s, gate_sigma):
    """CollarFilter._attach: append the fix to ``chain`` (≥ 0), the newest consistent
    chain, or a new one (dropping the oldest beyond MAX_CANDIDATES); its index."""
    if chain < 0:
        for c in range(n_cand[i] - 1, -1, -1):
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
def _adopt(i, chain, t, x, P, ever, counters, n_cand, cand_len, cand_t, cand_z, cand_r,
           accel_std, velocity_tau, v0):
    """CollarFilter._adopt: re-initialise on the chain's first fix, update through the
    rest."""
    xi = x[i]
    Pi = P[i]
    xi[0] = cand_z[i, chain, 0, 0]
    xi[1] = cand_z[i, chain, 0, 1]
    xi[2] = 0.0
    xi[3] = 0.0
    Pi[:, :] = 0.0
    Pi[0, 0] = cand_r[i, chain, 0, 0, 0]
    Pi[0, 1] = cand_r[i, chain, 0, 0, 1]
    Pi[1, 0] = cand_r[i, chain, 0, 1, 0]
    Pi[1, 1] = cand_r[i, chain, 0, 1, 1]
    Pi[2, 2] = Pi[3, 3] = v0 * v0
    t[i] = cand_t[i, chain, 0]
    xp = np.empty(4)
    Pp = np.empty((4, 4))
    for k in range(1, cand_len[i, chain]):
        _predict(xi, Pi, cand_t[i, chain, k] - t[i], accel_std, velocity_tau, xp, Pp)
        xi[:] = xp
        Pi[:, :] = Pp
        _update(xi, Pi, cand_z[i, chain, k, 0], cand_z[i, chain, k, 1], cand_r[i, chain, k])
        t[i] = cand_t[i, chain, k]
    n_cand[i] = 0
    ever[i] = True
    counters[i, _C_ACC] += 1


@_jit
def _process_batch(collar, stamp, east, north, status, R,
                   t, x, P, ever, last_pos, last_report, counters, n_cand, cand_jump,
                   cand_len, cand_t, cand_z, cand_r,
                   accel_std, velocity_tau, max_speed, cruise_speed, sprint_s, gate,
                   gate_sigma, v0, confirm, reacquire, confirm_lost, reinit_after_gap,
                   out_code, out_d2, out_x, out_P, out_seg):
    """CollarFilter.update for each fix of the batch, in order (see its comments)."""
    xp = np.empty(4)
    Pp = np.empty((4, 4))
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
            counters[i, _C_NO_FIX] += 1
        elif not (math.isfinite(z0) and math.isfinite(z1)):
            code = NAN
            counters[i, _C_NAN] += 1
        elif not math.isfinite(s):
            code = TIME
            counters[i, _C_TIME] += 1
        else:
            latest = t[i] if math.isfinite(t[i]) else -np.inf
            for c in range(n_cand[i]):
                latest = max(latest, cand_t[i, c, cand_len[i, c] - 1])
            if s <= latest:
                code = TIME
                counters[i, _C_TIME] += 1
        if code < 0:
            silence = s - last_pos[i]
            last_pos[i] = s
            if math.isfinite(t[i]) and silence > reinit_after_gap:
                t[i] = np.nan               # the track is lost
                n_cand[i] = 0
            chain = -1
            reason = -1                     # rejection reason if the chain is not adopted
            if not math.isfinite(t[i]):
                chain = _attach(i, -1, s, z0, z1, r, False, n_cand, cand_jump, cand_len,
                                cand_t, cand_z, cand_r, max_speed, cruise_speed, sprint_s,
                                gate_sigma)
                if cand_len[i, chain] < confirm_lost:
                    code = UNCONFIRMED
                    counters[i, _C_UNCONF] += 1
                else:
                    first = not ever[i]
                    _adopt(i, chain, t, x, P, ever, counters, n_cand, cand_len, cand_t,
                           cand_z, cand_r, accel_std, velocity_tau, v0)
                    if first:
                        code = ACCEPTED
                    else:
                        code = REINITIALISED
                        counters[i, _C_REINIT] += 1
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
                    chain = _attach(i, -1, s, z0, z1, r, True, n_cand, cand_jump, cand_len,
                                    cand_t, cand_z, cand_r, max_speed, cruise_speed,
                                    sprint_s, gate_sigma)
                else:
                    _predict(xi, Pi, tau, accel_std, velocity_tau, xp, Pp)
                    y0 = z0 - xp[0]
                    y1 = z1 - xp[1]
                    s00 = Pp[0, 0] + r[0, 0]
                    s01 = Pp[0, 1] + r[0, 1]
                    s10 = Pp[1, 0] + r[1, 0]
                    s11 = Pp[1, 1] + r[1, 1]
                    det = s00 * s11 - s01 * s10
                    d2 = (y0 * (s11 * y0 - s01 * y1) + y1 * (s00 * y1 - s10 * y0)) / det
                    innovation = math.hypot(y0, y1)
                    for c in range(n_cand[i] - 1, -1, -1):
                        if (_reach_ratio(i, c, s, z0, z1, r, cand_len, cand_t, cand_z,
                                         cand_r, max_speed, cruise_speed, sprint_s,
                                         gate_sigma) <= 1.0
                                and _chain_distance(i, c, z0, z1, cand_len, cand_z)
                                < innovation):
                            chain = _attach(i, c, s, z0, z1, r, cand_jump[i, c], n_cand,
                                            cand_jump, cand_len, cand_t, cand_z, cand_r,
                                            max_speed, cruise_speed, sprint_s, gate_sigma)
                            reason = SPEED if cand_jump[i, c] else GATE
                            break
                    if chain < 0 and d2 > gate:
                        reason = GATE
                        chain = _attach(i, -1, s, z0, z1, r, False, n_cand, cand_jump,
                                        cand_len, cand_t, cand_z, cand_r, max_speed,
                                        cruise_speed, sprint_s, gate_sigma)
                    if chain < 0:           # accepted: filterpy predict + update
                        xi[:] = xp
                        Pi[:, :] = Pp
                        _update(xi, Pi, z0, z1, r)
                        t[i] = s
                        n_cand[i] = 0
                        counters[i, _C_ACC] += 1
                        code = ACCEPTED
                if chain >= 0:
                    need = reacquire if cand_jump[i, chain] else confirm
                    if cand_len[i, chain] < need:
                        code = reason
                        if reason == SPEED:
                            counters[i, _C_SPEED] += 1
                        else:
                            counters[i, _C_GATE] += 1
                    else:
                        _adopt(i, chain, t, x, P, ever, counters, n_cand, cand_len, cand_t,
                               cand_z, cand_r, accel_std, velocity_tau, v0)
                        counters[i, _C_REINIT] += 1
                        code = REINITIALISED
        out_code[m] = code
        out_d2[m] = d2
        out_seg[m] = counters[i, _C_REINIT]
        if code == ACCEPTED or code == REINITIALISED:
            out_x[m] = x[i]
            if keep_P:
                out_P[m] = P[i]
        else:
            out_x[m] = np.nan
            if keep_P:
                out_P[m] = np.nan
