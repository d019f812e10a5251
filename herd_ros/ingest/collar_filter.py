"""One Kalman filter per GPS collar: constant velocity in the local ENU plane, with gating.

State ``x = [e, n, ve, vn]`` (m, m, m/s, m/s) in the datum's ENU frame; measurement
``z = [e, n]`` of a fix converted by :mod:`herd_ros.ingest.geodesy`. Built on
:class:`filterpy.kalman.KalmanFilter` (predict/update with per-step ``F``, ``Q``, ``R``).

Process model (variable Δt = τ), the *discrete white-noise acceleration* model of
Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and Navigation*
(2001), §6.3.3 (filterpy's ``Q_discrete_white_noise``): a piecewise-constant acceleration
of standard deviation ``accel_std`` (m/s²) over each interval, per axis::

    F(τ) = [[I, τ I], [0, I]],   G(τ) = [τ²/2, τ]ᵀ,   Q(τ) = accel_std² G Gᵀ ⊗ I₂
         = accel_std² [[τ⁴/4 I, τ³/2 I], [τ³/2 I, τ² I]]

Measurement noise ``R`` (2×2, m²) from ``NavSatFix.position_covariance`` (row-major 3×3 in
ENU, per the message definition) by ``position_covariance_type``:

* ``UNKNOWN`` (0), or any NaN/inf entry: ``default_position_std² I``;
* ``APPROXIMATED`` (1), ``KNOWN`` (3): the E/N block ``[[c0, c1], [c3, c4]]`` (symmetrised);
* ``DIAGONAL_KNOWN`` (2): ``diag(c0, c4)``;

then **floored**: eigenvalues below ``position_std_floor²`` are raised to it
(``R = V max(Λ, floor²) Vᵀ``), so a zero, negative or absurdly small covariance — common in
collar firmware that fills the field with zeros — is never trusted blindly (the weakness of
robot_localization's navsat_transform/EKF, which takes a zero covariance nearly at face
value). The default floor, 0.5 m, is below what any consumer GNSS collar achieves but still
bounds the Kalman gain; set it lower for RTK receivers.

Each fix goes through these checks in order; the first failing one rejects it with a reason
(and bumps its counter):

1. ``no_fix``: ``status == STATUS_NO_FIX`` (-1). (``STATUS_UNKNOWN`` (-2, Jazzy) is gated
   like any fix.)
2. ``nan``: east or north not finite (NaN/inf latitude or longitude). A NaN *altitude* is
   fine: the caller converts with ``nan_alt`` (see geodesy).
3. ``time``: stamp older than or equal to the last accepted one.
4. ``speed`` — the paper's speed gate (Schwager et al. 2007: 3 m/s), made noise-aware:
   reject if ``‖z − p̂‖ > max_speed·τ + c·σ`` where ``p̂`` is the last accepted filtered
   position, ``τ`` the time since it, ``σ² = λ_max(R + P_pp)`` and ``c = √χ²₂(gate_probability)``.
   Without the ``c·σ`` term a 3 m/s gate on raw 1 Hz fixes with 3 m noise would reject most
   genuine fixes (two fixes of a standing animal are ~5 m apart).
5. ``gate``: Mahalanobis gate on the innovation, ``yᵀ S⁻¹ y > χ²₂⁻¹(gate_probability)``,
   ``y = z − H x⁻``, ``S = H P⁻ Hᵀ + R``.

Not locking onto a jump (or onto a wrong first fix): consecutive rejected (speed/gate) fixes
are kept; when ``reinit_after_rejections`` of them in a row are mutually consistent (each
step passes the speed gate against the previous one), the filter re-initialises on the first
of them and runs plain updates through the rest (counter ``reinitialised``). Isolated jumps
in random directions are not mutually consistent and stay rejected. After a gap longer than
``reinit_after_gap`` seconds the next valid fix re-initialises the filter directly (the old
velocity means nothing by then).

Initialisation (first fix or re-init): position = the fix with covariance R, velocity 0 with
std ``initial_velocity_std`` (default = ``max_speed``).

Staleness: :meth:`CollarFilter.is_stale` is true when more than ``stale_after`` seconds have
passed since the last accepted fix; :meth:`CollarFilter.estimate_at` predicts the state
forward with the growing covariance of ``Q(τ)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter
from scipy.stats import chi2

from herd_ros.errors import HerdInputError

STATUS_NO_FIX = -1
COVARIANCE_TYPE_UNKNOWN = 0
COVARIANCE_TYPE_APPROXIMATED = 1
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2
COVARIANCE_TYPE_KNOWN = 3

#: Counter names, in the order diagnostics list them.
COUNTERS = ('accepted', 'rejected_no_fix', 'rejected_nan', 'rejected_time', 'rejected_gate',
            'rejected_speed', 'reinitialised')

_H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class FilterParams:
    """Parameters of a :class:`CollarFilter` (names as the ``gps_ingest`` node parameters).

    Attributes:
        accel_std: std of the white-noise acceleration (m/s²) of the process model.
        default_position_std: measurement std (m) for ``COVARIANCE_TYPE_UNKNOWN``.
        position_std_floor: smallest measurement std (m) ever used (floors every R).
        gate_probability: probability mass inside the Mahalanobis gate (χ², 2 dof).
        max_speed: the paper's speed gate (m/s).
        stale_after: a collar without an accepted fix for longer (s) is stale.
        initial_velocity_std: velocity std (m/s) at (re)initialisation; None = max_speed.
        reinit_after_rejections: consistent consecutive rejections that re-initialise.
        reinit_after_gap: a gap (s) after which the next valid fix re-initialises.
    """

    accel_std: float = 0.2
    default_position_std: float = 5.0
    position_std_floor: float = 0.5
    gate_probability: float = 0.999
    max_speed: float = 3.0
    stale_after: float = 30.0
    initial_velocity_std: float | None = None
    reinit_after_rejections: int = 5
    reinit_after_gap: float = 300.0

    def __post_init__(self):
        positive = ('accel_std', 'default_position_std', 'position_std_floor', 'max_speed',
                    'stale_after', 'reinit_after_gap')
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise HerdInputError(f'filter parameter {name} must be a positive number, '
                                     f'got {value!r}')
        if not 0.0 < self.gate_probability < 1.0:
            raise HerdInputError(f'filter parameter gate_probability must be in (0, 1), got '
                                 f'{self.gate_probability!r}')
        if self.initial_velocity_std is not None and not self.initial_velocity_std > 0:
            raise HerdInputError('filter parameter initial_velocity_std must be positive, '
                                 f'got {self.initial_velocity_std!r}')
        if int(self.reinit_after_rejections) < 1:
            raise HerdInputError('filter parameter reinit_after_rejections must be >= 1, '
                                 f'got {self.reinit_after_rejections!r}')

    @property
    def gate_threshold(self) -> float:
        """χ²₂ quantile of ``gate_probability``: the squared Mahalanobis gate."""
        return float(chi2.ppf(self.gate_probability, df=2))


@dataclass
class FixResult:
    """What the filter did with one fix.

    Attributes:
        accepted: the fix updated the state (also true for the fix that re-initialised it).
        reason: ``'accepted'``, ``'reinitialised'`` or the rejection reason
            (``'no_fix'``, ``'nan'``, ``'time'``, ``'speed'``, ``'gate'``).
        detail: one human-readable sentence (for diagnostics and logs).
        mahalanobis2: squared Mahalanobis distance of the innovation (NaN if not computed).
    """

    accepted: bool
    reason: str
    detail: str = ''
    mahalanobis2: float = float('nan')


@dataclass
class CollarState:
    """A filter state at data time ``t``: ``x`` (4,) [e, n, ve, vn], ``P`` (4, 4)."""

    t: float
    x: np.ndarray
    P: np.ndarray


def transition(tau):
    """``F(τ)`` for the state [e, n, ve, vn]; ``tau`` any shape -> (..., 4, 4)."""
    tau = np.asarray(tau, dtype=float)
    f = np.broadcast_to(np.eye(4), tau.shape + (4, 4)).copy()
    f[..., 0, 2] = tau
    f[..., 1, 3] = tau
    return f


def process_noise(tau, accel_std):
    """Discrete white-noise acceleration ``Q(τ)`` (Bar-Shalom et al. 2001, §6.3.3);
    ``tau`` any shape -> (..., 4, 4), m² / m²s⁻¹ / m²s⁻²."""
    tau = np.asarray(tau, dtype=float)
    var = float(accel_std) ** 2
    q = np.zeros(tau.shape + (4, 4))
    pp, pv, vv = var * tau ** 4 / 4.0, var * tau ** 3 / 2.0, var * tau ** 2
    for i in (0, 1):
        q[..., i, i] = pp
        q[..., i, i + 2] = pv
        q[..., i + 2, i] = pv
        q[..., i + 2, i + 2] = vv
    return q


def predict_state(x, P, tau, accel_std):
    """Constant-velocity prediction ``x⁻ = F x``, ``P⁻ = F P Fᵀ + Q`` over ``tau`` seconds.

    Vectorized: ``x`` (..., 4), ``P`` (..., 4, 4), ``tau`` (...) broadcast together; the
    herd clock uses it to carry filter states to the ticks.
    """
    f = transition(tau)
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    xp = np.einsum('...ij,...j->...i', f, x)
    Pp = np.einsum('...ij,...jk,...lk->...il', f, P, f) + process_noise(tau, accel_std)
    return xp, Pp


def measurement_covariance(position_covariance, covariance_type, default_position_std,
                           position_std_floor):
    """``R`` (2×2, m²) from a NavSatFix ``position_covariance`` (9 values or 3×3, ENU,
    row-major) and its ``position_covariance_type``, floored (see the module docstring)."""
    cov_type = int(covariance_type) if covariance_type is not None else 0
    c = None
    if cov_type != COVARIANCE_TYPE_UNKNOWN and position_covariance is not None:
        c = np.asarray(position_covariance, dtype=float).reshape(-1)
        if c.size != 9 or not np.isfinite(c[[0, 1, 3, 4]]).all():
            c = None
    if c is None:
        r = np.eye(2) * float(default_position_std) ** 2
    elif cov_type == COVARIANCE_TYPE_DIAGONAL_KNOWN:
        r = np.diag([c[0], c[4]])
    else:
        off = 0.5 * (c[1] + c[3])
        r = np.array([[c[0], off], [off, c[4]]])
    lam, v = np.linalg.eigh(r)
    lam = np.maximum(lam, float(position_std_floor) ** 2)
    return (v * lam) @ v.T


class CollarFilter:
    """Kalman filter of one collar, driven one fix at a time in data time.

    ``update`` takes the fix already in ENU (the node or :mod:`herd_ros.ingest.pipeline`
    converts with the shared datum). The state after the last accepted fix is ``t``, ``x``,
    ``P``; :meth:`estimate_at` predicts it to any later time without changing it.

    Attributes:
        params: the :class:`FilterParams`.
        kf: the underlying :class:`filterpy.kalman.KalmanFilter` (x is (4, 1)).
        t: data time (s) of the state, NaN before the first accepted fix.
        counters: fixes per outcome, keys :data:`COUNTERS`.
        last_report: stamp of the latest fix seen, accepted or not (NaN before any).
    """

    def __init__(self, params: FilterParams | None = None, **overrides):
        if params is None:
            params = FilterParams(**overrides)
        elif overrides:
            params = FilterParams(**{**params.__dict__, **overrides})
        self.params = params
        self._gate = params.gate_threshold
        self._gate_sigma = float(np.sqrt(self._gate))
        self._v0 = params.initial_velocity_std or params.max_speed
        self.kf = KalmanFilter(dim_x=4, dim_z=2)
        self.kf.H = _H.copy()
        self.t = float('nan')
        self.counters = {name: 0 for name in COUNTERS}
        self.last_report = float('nan')
        self._rejected_run: list[tuple[float, np.ndarray, np.ndarray]] = []

    # -- state ----------------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        return bool(np.isfinite(self.t))

    @property
    def x(self) -> np.ndarray:
        """State (4,) [e, n, ve, vn] at ``t``."""
        return self.kf.x[:, 0]

    @property
    def P(self) -> np.ndarray:
        """State covariance (4, 4) at ``t``."""
        return self.kf.P

    def state(self) -> CollarState:
        """A copy of the current state."""
        return CollarState(self.t, self.x.copy(), self.P.copy())

    def estimate_at(self, t: float) -> CollarState:
        """The state predicted to data time ``t`` (≥ ``self.t``); NaN before initialisation."""
        if not self.initialised:
            return CollarState(float(t), np.full(4, np.nan), np.full((4, 4), np.nan))
        x, P = predict_state(self.x, self.P, float(t) - self.t, self.params.accel_std)
        return CollarState(float(t), x, P)

    def is_stale(self, t: float) -> bool:
        """No accepted fix for more than ``stale_after`` seconds before ``t`` (or never)."""
        return not self.initialised or float(t) - self.t > self.params.stale_after

    # -- one fix --------------------------------------------------------------------------
    def update(self, stamp: float, east: float, north: float, *, status: int = 0,
               position_covariance=None, position_covariance_type: int = 0) -> FixResult:
        """Process one fix (stamp in s of data time, east/north in m about the datum)."""
        p = self.params
        stamp = float(stamp)
        if np.isfinite(stamp):
            self.last_report = (stamp if not np.isfinite(self.last_report)
                                else max(self.last_report, stamp))
        if status is not None and int(status) == STATUS_NO_FIX:
            return self._reject('no_fix', 'status is STATUS_NO_FIX')
        if not (np.isfinite(east) and np.isfinite(north)):
            return self._reject('nan', 'latitude or longitude is not finite')
        if not np.isfinite(stamp):
            return self._reject('time', 'stamp is not finite')
        if self.initialised and stamp <= self.t:
            return self._reject('time', f'stamp {stamp:.3f} is not after the last accepted '
                                        f'fix {self.t:.3f}')
        z = np.array([float(east), float(north)])
        r = measurement_covariance(position_covariance, position_covariance_type,
                                   p.default_position_std, p.position_std_floor)
        if not self.initialised or stamp - self.t > p.reinit_after_gap:
            first = not self.initialised
            self._initialise(stamp, z, r)
            self.counters['accepted'] += 1
            if not first:
                self.counters['reinitialised'] += 1
                return FixResult(True, 'reinitialised', f'gap longer than '
                                 f'{p.reinit_after_gap:g} s: re-initialised on this fix')
            return FixResult(True, 'accepted', 'first fix: initialised')

        tau = stamp - self.t
        # speed gate against the last accepted filtered position
        dist = float(np.hypot(*(z - self.x[:2])))
        sigma = float(np.sqrt(np.linalg.eigvalsh(r + self.P[:2, :2])[-1]))
        allowed = p.max_speed * tau + self._gate_sigma * sigma
        if dist > allowed:
            return self._reject_candidate(stamp, z, r, 'speed',
                                          f'{dist:.1f} m in {tau:.3g} s exceeds max_speed '
                                          f'{p.max_speed:g} m/s (allowed {allowed:.1f} m)')
        # Mahalanobis gate on the innovation
        x_saved, P_saved = self.kf.x.copy(), self.kf.P.copy()
        self.kf.predict(F=transition(tau), Q=Q_discrete_white_noise(
            dim=2, dt=tau, var=p.accel_std ** 2, block_size=2, order_by_dim=False))
        y = z - self.kf.x[:2, 0]
        s = self.kf.P[:2, :2] + r
        d2 = float(y @ np.linalg.solve(s, y))
        if d2 > self._gate:
            self.kf.x, self.kf.P = x_saved, P_saved
            return self._reject_candidate(stamp, z, r, 'gate',
                                          f'Mahalanobis distance² {d2:.1f} exceeds the '
                                          f'{p.gate_probability:g} gate {self._gate:.2f}',
                                          d2)
        self.kf.update(z, R=r)
        self.t = stamp
        self._rejected_run.clear()
        self.counters['accepted'] += 1
        return FixResult(True, 'accepted', '', d2)

    # -- internals ------------------------------------------------------------------------
    def _initialise(self, stamp, z, r):
        self.kf.x = np.array([[z[0]], [z[1]], [0.0], [0.0]])
        P = np.zeros((4, 4))
        P[:2, :2] = r
        P[2, 2] = P[3, 3] = self._v0 ** 2
        self.kf.P = P
        self.t = stamp
        self._rejected_run.clear()

    def _reject(self, reason, detail, d2=float('nan')):
        self.counters[f'rejected_{reason}'] += 1
        return FixResult(False, reason, detail, d2)

    def _reject_candidate(self, stamp, z, r, reason, detail, d2=float('nan')):
        """Reject a fix that failed a gate, and re-initialise if the run of such rejections
        is long and self-consistent (see the module docstring)."""
        run = self._rejected_run
        if run:
            t_prev, z_prev, r_prev = run[-1]
            tau = stamp - t_prev
            sigma = float(np.sqrt(np.linalg.eigvalsh(r + r_prev)[-1]))
            consistent = (tau > 0 and float(np.hypot(*(z - z_prev)))
                          <= self.params.max_speed * tau + self._gate_sigma * sigma)
            if not consistent:
                run.clear()
        run.append((stamp, z, r))
        if len(run) < int(self.params.reinit_after_rejections):
            return self._reject(reason, detail, d2)
        # a consistent track the filter refuses: the filter is what is wrong
        replay = list(run)
        self._initialise(replay[0][0], replay[0][1], replay[0][2])
        for t_k, z_k, r_k in replay[1:]:
            tau = t_k - self.t
            self.kf.predict(F=transition(tau), Q=Q_discrete_white_noise(
                dim=2, dt=tau, var=self.params.accel_std ** 2, block_size=2,
                order_by_dim=False))
            self.kf.update(z_k, R=r_k)
            self.t = t_k
        # the earlier fixes of the run stay counted as rejected; this one re-initialised
        self.counters['accepted'] += 1
        self.counters['reinitialised'] += 1
        return FixResult(True, 'reinitialised',
                         f'{len(replay)} consistent consecutive rejections: re-initialised '
                         f'on them', d2)
