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
* one compiled loop (:mod:`herd_ros.ingest.collar_kernels`) over a batch of fixes in
  arrival order. The loop cannot be vectorised across fixes (each fix of a collar starts
  from the state the previous one left) and branches per fix (checks, chains, adoption);
  every step in it is the 2 × 2 / 4 × 4 algebra of the reference written out in scalars;
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

The loops are compiled at install, ahead of time, where a C compiler is present, and by
numba on first use otherwise (:mod:`herd_ros.ingest.aot`); :data:`KERNELS` says which.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from herd_ros.ingest import aot, collar_threads
from herd_ros.ingest.collar_filter import COUNTERS, FilterParams
from herd_ros.ingest.fix_outcomes import (  # noqa: F401 - the codes, named here too
    ACCEPTED, GATE, MAX_CANDIDATES, NAN, NO_FIX, OUTCOMES, RANGE, REINITIALISED, SPEED,
    TIME, UNCONFIRMED)

#: the compiled loops this process runs (:func:`herd_ros.ingest.aot.load_kernels`):
#: ``KERNELS.kind`` is ``'aot'`` (built at install, no numba in the process) or ``'jit'``
#: (numba); None without either
KERNELS = aot.load_kernels()
AVAILABLE = KERNELS is not None


def measurement_covariances(cov_type, cov9, default_position_std,
                            position_std_floor) -> np.ndarray:
    """``R`` (M, 2, 2) of M fixes from their NavSatFix covariance type (M,) and
    ``position_covariance`` (M, 9; not read when no type is known): the rules of
    :func:`~herd_ros.ingest.collar_filter.measurement_covariance`, vectorised
    (``default_position_std``, ``position_std_floor``: one std, or (M,), each fix's
    collar's).

    The floor ``R = V max(Λ, floor²) Vᵀ`` in closed form: with eigenvalues λ₁ ≤ λ₂ and
    the projector ``Π₁ = (A − λ₂ I)/(λ₁ − λ₂)`` on the first eigenvector,
    ``R = max(λ₂, f²) I + (max(λ₁, f²) − max(λ₂, f²)) Π₁``; ``R = A`` when λ₁ ≥ f².
    """
    cov_type = np.ascontiguousarray(cov_type, dtype=np.int64).reshape(-1)
    if cov_type.any():
        c = np.ascontiguousarray(cov9, dtype=float).reshape(len(cov_type), 9)
    else:           # no fix has a covariance: the kernel reads none (a type 0 is unknown)
        c = _NO_COVARIANCE
    r = np.empty((len(cov_type), 2, 2))
    d2 = _per(np.asarray(default_position_std, dtype=float) ** 2, len(cov_type))
    f2 = _per(np.asarray(position_std_floor, dtype=float) ** 2, len(cov_type))
    KERNELS.covariances(cov_type, c, d2, f2, r)
    return r


def predict_states(x, P, tau, accel_std, velocity_tau=0.0):
    """:func:`~herd_ros.ingest.collar_filter.predict_state` for M states at once, compiled:
    ``x`` (M, 4), ``P`` (M, 4, 4), ``tau`` (M,) -> (x⁻ (M, 4), P⁻ (M, 4, 4)); the motion
    model one for all or per state ((M,) arrays). The herd clock carries every collar's
    state to a tick with it."""
    x = np.ascontiguousarray(x, dtype=float).reshape(-1, 4)
    P = np.ascontiguousarray(P, dtype=float).reshape(-1, 4, 4)
    tau = np.ascontiguousarray(np.broadcast_to(np.asarray(tau, dtype=float), (len(x),)))
    xo = np.empty_like(x)
    Po = np.empty_like(P)
    KERNELS.predict_many(x, P, tau, _per(accel_std, len(x)), _per(velocity_tau, len(x)),
                         xo, Po)
    return xo, Po


#: the covariance rows passed for a batch in which no fix has one (never read)
_NO_COVARIANCE = np.full((1, 9), np.nan)


def _per(value, n: int) -> np.ndarray:
    """A scalar or (n,) value as a contiguous float (n,) array."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(value, dtype=float), (n,)))


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

    @classmethod
    def empty(cls, m: int, keep_covariance: bool = True) -> FixBatch:
        """A batch of ``m`` rows to be written (``P`` of shape (0, 4, 4) without
        ``keep_covariance``)."""
        return cls(np.empty(m, np.int8), np.empty(m), np.empty((m, 4)),
                   np.empty((m if keep_covariance else 0, 4, 4)), np.empty(m, np.int64))

    def rows(self, sl: slice) -> FixBatch:
        """Rows ``sl`` of this batch as views (written through)."""
        return FixBatch(self.outcome[sl], self.mahalanobis2[sl], self.x[sl], self.P[sl],
                        self.segment[sl])

    def put(self, at, part: FixBatch):
        """Write ``part`` into rows ``at`` (indices) of this batch."""
        for name in ('outcome', 'mahalanobis2', 'x', 'P', 'segment'):
            if len(getattr(self, name)):
                getattr(self, name)[at] = getattr(part, name)


class CollarBank:
    """The filters of ``n`` collars (indices 0..n-1), driven by batches of fixes.

    Usage::

        bank = CollarBank(len(agents), FilterParams(...))
        batch = bank.process(collar, stamp, east, north, status, R)
        batch.outcome, batch.x                  # per fix
        bank.t, bank.x, bank.P, bank.counters   # per collar, after the batch

    ``params`` may be replaced between batches (the node's live parameters). Each collar's
    motion model and default measurement std are arrays, ``accel_std``, ``velocity_tau``
    and ``position_std`` (n,), set from ``params`` and replaced per collar by a fitted
    model (:meth:`set_motion`, :mod:`herd_ros.ingest.motion_fit`).
    """

    def __init__(self, n: int, params: FilterParams | None = None):
        if not AVAILABLE:  # pragma: no cover
            raise RuntimeError('CollarBank needs its compiled kernels (built at install, or '
                               'numba); use CollarFilter instead')
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
        # [n, Σx, Σy, Σx², Σxy, Σy²] of each collar's accepted states: its range
        self.range_moments = np.zeros((n, 6))
        # two slots of [t, e, n, r_ee, r_en, r_nn, fixes left, 1 if left for a chain else
        # 0]: the place each track left, and a later one beside it (t NaN: none;
        # CollarFilter.left_place, .left_recent)
        self.left_place = np.full((n, 16), np.nan)
        self.accel_std = np.full(n, float(self.params.accel_std))
        self.velocity_tau = np.full(n, float(self.params.velocity_tau))
        self.position_std = np.full(n, float(self.params.default_position_std))
        self.position_floor = np.full(n, float(self.params.position_std_floor))
        self.hdop_scaled = np.zeros(n, bool)    # a fix's default std × its HDOP

    def set_motion(self, i, accel_std, velocity_tau, position_std=None, floor=None,
                   hdop=None):
        """Collar(s) ``i`` move by this model from their next fix on (``position_std``:
        the std of their fixes without a covariance, ``floor`` the smallest std of any of
        their fixes, ``hdop``: that std is ``position_std`` × the fix's HDOP; None keeps
        them)."""
        self.accel_std[i] = accel_std
        self.velocity_tau[i] = velocity_tau
        if position_std is not None:
            self.position_std[i] = position_std
        if floor is not None:
            self.position_floor[i] = floor
        if hdop is not None:
            self.hdop_scaled[i] = hdop

    @staticmethod
    def warm_up():
        """Load the compiled loop (from numba's cache: ~0.3 s the first time in a process;
        instant when compiled ahead of time) so that the first fixes of a live node do
        not wait for it."""
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

    def measurement_covariances(self, cov_type, cov9, collar=None, hdop=None) -> np.ndarray:
        """``R`` (M, 2, 2) for a batch, with this bank's floor and default std (each
        fix's collar's, given ``collar`` (M,); else ``params``'); ``hdop`` (M,), NaN where
        none: the default std of a fix of a collar whose model takes the HDOP
        (:attr:`hdop_scaled`) is its collar's × its HDOP."""
        if collar is None:
            return measurement_covariances(cov_type, cov9, self.params.default_position_std,
                                           self.params.position_std_floor)
        collar = np.asarray(collar, dtype=np.int64)
        std = self.position_std[collar]
        if hdop is not None:
            h = np.asarray(hdop, dtype=float)
            std = np.where(self.hdop_scaled[collar] & np.isfinite(h), std * h, std)
        return measurement_covariances(cov_type, cov9, std, self.position_floor[collar])

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
            out = FixBatch.empty(m, keep_covariance)
        # a live batch (a few fixes) is never split: no count per collar for it
        parts = (collar_threads.split(np.bincount(collar, minlength=self.n))
                 if m >= collar_threads.MIN_WORK else [])
        if len(parts) > 1:
            self._process_parts(parts, collar, stamp, east, north, status, R, out)
            return out
        self._process(collar, stamp, east, north, status, R, out)
        return out

    def _process_parts(self, parts, collar, stamp, east, north, status, R, out):
        """:meth:`_process` of the fixes of each part (a slice of the collars) in a thread
        of its own (:mod:`~herd_ros.ingest.collar_threads`), each part's fixes in their
        order, the results written back to their rows of ``out``."""
        edges = np.array([sl.start for sl in parts[1:]], np.int64)
        which = np.searchsorted(edges, collar, side='right')
        keep_P = out.P.shape[0] > 0
        if (np.diff(which) >= 0).all():
            # each part's fixes in one block (a file's round, by collar): views, no copies
            bounds = np.searchsorted(which, np.arange(len(parts) + 1))

            def block(k):
                sl = slice(int(bounds[k]), int(bounds[k + 1]))
                return lambda: self._process(collar[sl], stamp[sl], east[sl], north[sl],
                                             status[sl], R[sl], out.rows(sl))
            collar_threads.run(block(k) for k in range(len(parts)))
            return

        def part(k):
            rows = np.flatnonzero(which == k)

            def call():
                res = FixBatch.empty(len(rows), keep_P)
                self._process(collar[rows], stamp[rows], east[rows], north[rows],
                              status[rows], R[rows], res)
                return rows, res
            return call

        for rows, res in collar_threads.run(part(k) for k in range(len(parts))):
            out.outcome[rows] = res.outcome
            out.mahalanobis2[rows] = res.mahalanobis2
            out.x[rows] = res.x
            if keep_P:
                out.P[rows] = res.P
            out.segment[rows] = res.segment

    def _process(self, collar, stamp, east, north, status, R, out):
        """One call of the compiled ``process_batch`` (arguments as :meth:`process`,
        contiguous)."""
        out_code, out_d2, out_x, out_P, out_seg = (out.outcome, out.mahalanobis2, out.x,
                                                   out.P, out.segment)
        p = self.params
        gate = p.gate_threshold
        KERNELS.process_batch(
            collar, stamp, east, north, status, R,
            self.t, self.x, self.P, self.ever, self.last_position_fix, self.last_report,
            self.counters, self.n_candidates, self.cand_jump, self.cand_len, self.cand_t,
            self.cand_z, self.cand_r, self.range_moments, self.left_place,
            self.accel_std, self.velocity_tau, float(p.max_speed),
            float(p.cruise_speed), float(p.sprint_s), gate, math.sqrt(gate),
            float(p.initial_velocity_std or p.max_speed),
            int(p.confirm_fixes), int(p.reacquire_fixes),
            int(p.confirm_fixes_lost), float(p.reinit_after_gap),
            float(p.range_sigmas), float(p.range_margin), int(p.range_min_fixes),
            float(p.walk[0]) if p.walk is not None else 0.0,
            float(p.walk[1]) if p.walk is not None else 0.0, float(p.walk_probability),
            float(p.walk_position_std or 0.0) ** 2,
            out_code, out_d2, out_x, out_P, out_seg)
