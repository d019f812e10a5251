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
4. ``speed`` — a kinematic envelope, the paper's speed gate (Schwager et al. 2007: 3 m/s)
   made noise-aware and duty-cycle-aware: reject if ``‖z − p̂‖ > d_max(τ) + c·σ`` where
   ``p̂`` is the last accepted filtered position, ``τ`` the time since it,
   ``σ² = λ_max(R + P_pp)``, ``c = √χ²₂(gate_probability)`` and

       d_max(τ) = max_speed · min(τ, sprint_s) + cruise_speed · max(τ − sprint_s, 0)

   Animals reach ``max_speed`` only for short bursts; over minutes their average speed is
   bounded by a lower travel speed. With 1 Hz collars the envelope is the paper's gate;
   with duty-cycled collars (a fix every 30 s to 5 min) it stops an outlier a few hundred
   metres off from passing merely because the interval was long. Without the ``c·σ`` term
   a 3 m/s gate on raw 1 Hz fixes with 3 m noise would reject most genuine fixes.
5. ``gate``: Mahalanobis gate on the innovation, ``yᵀ S⁻¹ y > χ²₂⁻¹(gate_probability)``,
   ``y = z − H x⁻``, ``S = H P⁻ Hᵀ + R``.

**Outlier bursts and genuine relocations** (reacquisition). Rejected fixes are not thrown
away: they are kept as *candidate tracks* (chains of mutually consistent fixes, each link
passing the speed envelope against the previous one), a two-hypothesis form of multiple
hypothesis tracking (Reid 1979; track confirmation by M consecutive detections as in
Blackman & Popoli, *Design and Analysis of Modern Tracking Systems*, 1999, §3.2). The
current track is replaced by a candidate (re-initialised on its first fix and updated
through the rest; counter ``reinitialised``; a fix of the chain outside the gate of the
track so far starts it afresh on that fix — a chain of ``reacquire_fixes`` fixes can span
an hour and a move of a kilometre that the collar's own model, fitted to a grazing animal,
follows only part of the way: measured on real cattle collars, the adopted track came out
460 m short of the chain's last fix and refused the fixes after it) when:

* the candidate was **reachable** — its first fix passed the speed envelope and failed only
  the Mahalanobis gate (the animal could have walked there: a relocation to water) — and has
  ``confirm_fixes`` consistent fixes (default 3: the track follows within three fixes);
* the candidate began with a **jump** — its first fix failed the speed envelope (no animal
  gets there in the time: a GPS outlier burst) — and has ``reacquire_fixes`` consistent
  fixes (default 12, longer than an outlier burst), so a track that really is wrong (say it
  started on an outlier) is still left in the end. While such a chain is open, a fix
  consistent with it belongs to it even if the track's envelope, grown with the time since
  its last accepted fix, would now admit it, as long as it is nearer to the chain's fixes
  than to the track's prediction (nearest-neighbour association, Bar-Shalom & Fortmann
  1988): a burst cannot make itself plausible by lasting (the same holds for a reachable
  chain). A fix continues a chain when it is within reach of *any* of the chain's fixes:
  the fixes of a burst scatter about its wrong place (measured on generated bursts 0.8 km
  off: consecutive fixes 140 m apart 40 s apart), and a chain tested against its last fix
  only broke up, letting the rest of the burst start a new, reachable chain that was
  adopted after three fixes.

**Far outside the collar's range.** Over minutes almost everything is "reachable", so the
speed envelope alone lets a burst a few hundred metres off, or kilometres off after a
long interval, confirm on ``confirm_fixes``. A chain whose first fix lies far outside the
range the collar has kept so far — the running mean μ and covariance Σ of its accepted
states, once it has ``range_min_fixes`` — is treated as a jump and needs
``reacquire_fixes``: Mahalanobis r = √(dᵀ (Σ + 1 m² I)⁻¹ d) > ``range_sigmas`` with
d = z − μ, and ‖d‖ more than ``range_margin`` (200 m) beyond 3 √λ_max(Σ + I) — whether or
not the track's gate would take the fix. Measured on the duty-cycled herds of
``test/bench/bench_tracking.py`` (the range of the track's own states before each fix,
3 seeds): the rule takes 96 % of the cows' burst fixes and 98 % of the steers' and none of
their 13 623 and 45 695 genuine ones (with a 100 m margin: 3 genuine cows' fixes, and the
cows' relocations between grazing places were followed late). A genuine move far beyond
the range is followed after ``reacquire_fixes`` fixes instead of ``confirm_fixes``, and the
range grows to take it in: the place the track is at counts as part of the range, so a fix
within ``range_margin`` (beyond 3 σ) of a track that itself lies far outside the range is
not far. (Without that, the range grew by one state per adoption and every fix at the new
place started another jump chain: measured on a real cattle logger driven 1.4 km, the
track accepted one fix in twelve there and was stale between.) The same rule applies to
a lost track's first chain (and a fix inside the range joins no such chain), and a chain
that a fix far outside the range joins becomes a jump chain: a burst fix after a silence
no longer confirms, with one fix at home, a lost track's two-fix chain.

**The place the track left.** A burst a few hundred metres off whose fixes are within reach
of the track and of each other looks like a relocation and is followed on
``confirm_fixes``; when the fixes then come back to where the animal was, they are beyond
the speed envelope of the track (now at the burst) and were treated as a jump, so the track
stayed on the burst's place for ``reacquire_fixes`` fixes and went stale (measured on the
synthetic collared cows: a burst of five fixes 330 m off, taken, then six genuine fixes
rejected). Both hypotheses are now kept until the fixes decide: when the track moves to a
reachable chain, the place it left (its last state's position and covariance) is kept for
its next ``reacquire_fixes`` accepted fixes. A fix the track refuses that lies inside the gate of
that place (its position and covariance, velocity 0, predicted to the fix with the
collar's own motion model: the animal stayed there) takes the track back at once,
updated with that fix, and the burst's place is forgotten; a fix beyond the track's
envelope but within the envelope of that place (not its gate) starts (or continues) a
reachable chain, confirmed on ``confirm_fixes``. When the new place holds for
``reacquire_fixes`` accepted fixes, the left place is dropped (a real relocation). The
same place is kept when the track takes a fix by the walk component of its motion
mixture alone (outside the gate of its own model): a single fix a few hundred metres
off after a few minutes' silence passes the walk's gate, and the fixes that come back
are then beyond reach of the track. Such a place serves the return only; it does not
make a fix within its envelope a reachable chain (its envelope, grown over the hours a
duty-cycled collar may take to accept ``reacquire_fixes`` fixes, would admit bursts
kilometres off). A second such fix while the first place is still held keeps its own
place beside it (``left_recent``; the first is not replaced: a scattered burst's second
fix would then hide the place the burst began from), and a fix the track refuses is
tried against the later place first. With one place, a logger that left for a fix again
a few fixes after a move had its fixes back refused as a jump until it went stale.
Measured on real GPS collars of cattle (doc/gps_ingest.md), where a logger's fixes leave
for one to a few fixes and come back.

Any fix the track accepts closes the open candidates (the burst is over). Isolated outliers
in random directions never form a chain.

**Lost tracks** (start of data, a late-starting collar, or a collar silent — no fix with a
position at all — for longer than ``reinit_after_gap``; a long run of *rejected* fixes is a
burst, handled above, not a silence): the old velocity means nothing, and neither does one
lone fix, which may be an outlier. The fixes form candidate chains and the first with
``confirm_fixes_lost`` (default 2) consistent fixes initialises the track; until then the
collar has no estimate.

Initialisation (first fix of a confirmed chain): position = the fix with covariance R,
velocity 0 with std ``initial_velocity_std`` (default = ``max_speed``).

Staleness: :meth:`CollarFilter.is_stale` is true when more than ``stale_after`` seconds have
passed since the last accepted fix; :meth:`CollarFilter.estimate_at` predicts the state
forward with the growing covariance of ``Q(τ)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from herd_ros.errors import HerdInputError

STATUS_NO_FIX = -1
COVARIANCE_TYPE_UNKNOWN = 0
COVARIANCE_TYPE_APPROXIMATED = 1
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2
COVARIANCE_TYPE_KNOWN = 3

#: Counter names, in the order diagnostics list them.
COUNTERS = ('accepted', 'rejected_no_fix', 'rejected_nan', 'rejected_time', 'rejected_gate',
            'rejected_speed', 'rejected_range', 'rejected_unconfirmed', 'reinitialised')

_H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class FilterParams:
    """Parameters of a :class:`CollarFilter` (names as the ``gps_ingest`` node parameters).

    Attributes:
        accel_std: std of the white-noise acceleration (m/s²) of the process model.
        velocity_tau: velocity correlation time (s) of the correlated random walk; 0 =
            constant velocity (see :func:`process_noise`).
        default_position_std: measurement std (m) for ``COVARIANCE_TYPE_UNKNOWN``.
        position_std_floor: smallest measurement std (m) ever used (floors every R).
        gate_probability: probability mass inside the Mahalanobis gate (χ², 2 dof).
        max_speed: the paper's speed gate (m/s): the fastest an animal moves, briefly.
        cruise_speed: the fastest average speed (m/s) sustained beyond ``sprint_s``.
        sprint_s: how long (s) ``max_speed`` can be kept up.
        stale_after: a collar without an accepted fix for longer (s) is stale.
        initial_velocity_std: velocity std (m/s) at (re)initialisation; None = max_speed.
        confirm_fixes: consistent fixes that confirm a reachable candidate (a relocation).
        reacquire_fixes: consistent fixes that confirm a candidate that began with a jump.
        confirm_fixes_lost: consistent fixes that start a lost (or new) track.
        reinit_after_gap: a gap (s) after which the track is lost (the old state is dropped).
        range_sigmas, range_margin, range_min_fixes: a candidate whose first fix is farther
            than ``range_sigmas`` (Mahalanobis) and ``range_margin`` metres beyond 3 σ_max
            from the range of the collar's accepted states (once it has
            ``range_min_fixes``) needs ``reacquire_fixes`` (module docstring);
            ``range_sigmas`` 0 turns the rule off.
        walk_accel_std, walk_velocity_tau: a second, broader motion model (a walk) beside
            the collar's own (fitted) one; None = none. The motion model is then a
            two-component scale mixture of Q ("graze" with the own model, "walk" with
            probability ``walk_probability``): each fix updates both components and the
            posterior mixture is collapsed to its first two moments (GPB1, Bar-Shalom, Li
            & Kirubarajan 2001, §11.6), and only a fix outside the gate of both is an
            outlier. So a fitted model tight enough to average a resting animal's fixes
            still follows a walk at once.
        walk_probability: prior probability π_w of the walk component per fix.
        walk_position_std: std (m) added to every fix's under the walk component (None =
            none): the walk stands for "something unusual", a fast move or a fix a few
            metres off, so a fix that neither component's gate takes as it is can still be
            taken at a discount (a scale mixture in R as well as Q: a heavy-tailed
            measurement model in place of a bare gate).
    """

    accel_std: float = 0.2
    velocity_tau: float = 0.0
    default_position_std: float = 5.0
    position_std_floor: float = 0.5
    gate_probability: float = 0.999
    max_speed: float = 3.0
    cruise_speed: float = 1.0
    sprint_s: float = 60.0
    stale_after: float = 30.0
    initial_velocity_std: float | None = None
    confirm_fixes: int = 2
    reacquire_fixes: int = 12
    confirm_fixes_lost: int = 2
    reinit_after_gap: float = 300.0
    walk_accel_std: float | None = None
    walk_velocity_tau: float | None = None
    walk_probability: float = 0.05
    walk_position_std: float | None = None
    range_sigmas: float = 6.0
    range_margin: float = 200.0
    range_min_fixes: int = 30

    def __post_init__(self):
        positive = ('accel_std', 'default_position_std', 'position_std_floor', 'max_speed',
                    'cruise_speed', 'stale_after', 'reinit_after_gap')
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise HerdInputError(f'filter parameter {name} must be a positive number, '
                                     f'got {value!r}')
        if not (np.isfinite(self.velocity_tau) and self.velocity_tau >= 0):
            raise HerdInputError(f'filter parameter velocity_tau must be >= 0 (0 = constant '
                                 f'velocity), got {self.velocity_tau!r}')
        if not (np.isfinite(self.sprint_s) and self.sprint_s >= 0):
            raise HerdInputError(f'filter parameter sprint_s must be >= 0, got '
                                 f'{self.sprint_s!r}')
        if self.cruise_speed > self.max_speed:
            raise HerdInputError(f'filter parameter cruise_speed ({self.cruise_speed!r}) must '
                                 f'not exceed max_speed ({self.max_speed!r})')
        if not 0.0 < self.gate_probability < 1.0:
            raise HerdInputError(f'filter parameter gate_probability must be in (0, 1), got '
                                 f'{self.gate_probability!r}')
        if self.initial_velocity_std is not None and not self.initial_velocity_std > 0:
            raise HerdInputError('filter parameter initial_velocity_std must be positive, '
                                 f'got {self.initial_velocity_std!r}')
        if self.walk_accel_std is not None and not (np.isfinite(self.walk_accel_std)
                                                    and self.walk_accel_std > 0):
            raise HerdInputError('filter parameter walk_accel_std must be positive, got '
                                 f'{self.walk_accel_std!r}')
        if self.walk_velocity_tau is not None and not (np.isfinite(self.walk_velocity_tau)
                                                       and self.walk_velocity_tau >= 0):
            raise HerdInputError('filter parameter walk_velocity_tau must be >= 0, got '
                                 f'{self.walk_velocity_tau!r}')
        if not 0.0 < self.walk_probability < 1.0:
            raise HerdInputError('filter parameter walk_probability must be in (0, 1), got '
                                 f'{self.walk_probability!r}')
        if not (np.isfinite(self.range_sigmas) and self.range_sigmas >= 0):
            raise HerdInputError('filter parameter range_sigmas must be >= 0 (0 = off), got '
                                 f'{self.range_sigmas!r}')
        if not (np.isfinite(self.range_margin) and self.range_margin >= 0):
            raise HerdInputError('filter parameter range_margin must be >= 0, got '
                                 f'{self.range_margin!r}')
        for name in ('confirm_fixes', 'reacquire_fixes', 'confirm_fixes_lost',
                     'range_min_fixes'):
            if int(getattr(self, name)) < 1:
                raise HerdInputError(f'filter parameter {name} must be >= 1, '
                                     f'got {getattr(self, name)!r}')

    @property
    def gate_threshold(self) -> float:
        """χ²₂ quantile of ``gate_probability``: the squared Mahalanobis gate (closed form:
        the χ² CDF with 2 degrees of freedom is ``1 − e^{−x/2}``, so ``x = −2 ln(1 − p)``)."""
        return float(-2.0 * math.log1p(-self.gate_probability))

    @property
    def walk(self) -> tuple[float, float] | None:
        """(accel_std, velocity_tau) of the walk model, or None (see the attributes)."""
        if self.walk_accel_std is None and self.walk_velocity_tau is None:
            return None
        return (self.accel_std if self.walk_accel_std is None else self.walk_accel_std,
                self.velocity_tau if self.walk_velocity_tau is None
                else self.walk_velocity_tau)

    def reach(self, tau):
        """``d_max(τ)`` (m): the farthest an animal travels in ``tau`` seconds (module
        docstring, check 4)."""
        tau = np.maximum(np.asarray(tau, dtype=float), 0.0)
        sprint = np.minimum(tau, self.sprint_s)
        return self.max_speed * sprint + self.cruise_speed * (tau - sprint)


@dataclass
class LeftPlace:
    """Where a track was (its last accepted state's position ``z`` and covariance ``r`` at
    ``t``) before it moved to a reachable chain (``for_chain``) or took a fix by its walk
    component alone, kept for its next ``fixes_left`` accepted fixes (module docstring:
    *the place the track left*)."""

    t: float
    z: np.ndarray
    r: np.ndarray
    fixes_left: int
    for_chain: bool = True

    def reaches(self, stamp, z, r, params, gate_sigma) -> bool:
        """The fix is within the speed envelope of this place: ``‖z − z_left‖ ≤
        d_max(stamp − t) + c·σ``, ``σ² = λ_max(R + r)``."""
        sigma = float(np.sqrt(np.linalg.eigvalsh(r + self.r)[-1]))
        return float(np.hypot(*(z - self.z))) <= float(params.reach(stamp - self.t)) \
            + gate_sigma * sigma


def outside_range(moments, z, sigmas: float, margin: float, min_fixes: int) -> bool:
    """Whether ``z`` (2,) is far outside the range of a collar's accepted states,
    ``moments`` = [n, Σx, Σy, Σx², Σxy, Σy²] (FilterParams.range_sigmas, the module
    docstring); False before ``min_fixes`` states or with ``sigmas`` 0."""
    n = float(moments[0])
    if sigmas <= 0 or n < max(int(min_fixes), 1):
        return False
    mx, my = moments[1] / n, moments[2] / n
    a = moments[3] / n - mx * mx + 1.0
    b = moments[4] / n - mx * my
    c = moments[5] / n - my * my + 1.0
    dx, dy = float(z[0]) - mx, float(z[1]) - my
    det = a * c - b * b
    r2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det
    top = 0.5 * (a + c) + math.sqrt(0.25 * (a - c) ** 2 + b * b)
    return bool(r2 > sigmas * sigmas and math.hypot(dx, dy) - 3.0 * math.sqrt(top) > margin)


@dataclass
class FixResult:
    """What the filter did with one fix.

    Attributes:
        accepted: the fix updated the state (also true for the fix that re-initialised it).
        reason: ``'accepted'``, ``'reinitialised'`` or the rejection reason
            (``'no_fix'``, ``'nan'``, ``'time'``, ``'speed'``, ``'gate'``, ``'range'``,
            ``'unconfirmed'``).
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


def transition(tau, velocity_tau: float = 0.0):
    """``F(τ)`` for the state [e, n, ve, vn]; ``tau`` any shape -> (..., 4, 4).

    ``velocity_tau`` 0: constant velocity, ``[[I, τI], [0, I]]``. ``velocity_tau`` = 1/β > 0:
    the integrated Ornstein-Uhlenbeck velocity of the continuous-time correlated random walk
    (Johnson, London, Lea & Durban 2008, *Ecology* 89:1208, eq. 3):
    ``[[I, (1 − e^{−βτ})/β I], [0, e^{−βτ} I]]``.
    """
    tau = np.asarray(tau, dtype=float)
    f = np.broadcast_to(np.eye(4), tau.shape + (4, 4)).copy()
    if velocity_tau and velocity_tau > 0:
        tau = np.maximum(tau, 0.0)
        beta = 1.0 / float(velocity_tau)
        reach = -np.expm1(-beta * tau) / beta
        decay = np.exp(-beta * tau)
        f[..., 0, 2] = f[..., 1, 3] = reach
        f[..., 2, 2] = f[..., 3, 3] = decay
        return f
    f[..., 0, 2] = tau
    f[..., 1, 3] = tau
    return f


def process_noise(tau, accel_std, velocity_tau: float = 0.0):
    """``Q(τ)`` of the motion model; ``tau`` any shape -> (..., 4, 4), m² / m²s⁻¹ / m²s⁻².

    ``velocity_tau`` 0: discrete white-noise acceleration (Bar-Shalom et al. 2001, §6.3.3),
    ``accel_std² [[τ⁴/4, τ³/2], [τ³/2, τ²]] ⊗ I₂``.

    ``velocity_tau`` = 1/β > 0: the continuous-time correlated random walk (Johnson et al.
    2008, eq. 4), velocity an Ornstein-Uhlenbeck process ``dv = −βv dt + q^½ dW`` with
    ``q = accel_std²`` (stationary speed std per axis ``accel_std·√(velocity_tau/2)``)::

        Q_vv = q/(2β) (1 − e^{−2βτ})
        Q_pv = q/(2β²) (1 − e^{−βτ})²
        Q_pp = q/β² (τ − 2(1 − e^{−βτ})/β + (1 − e^{−2βτ})/(2β))

    Over intervals much longer than ``velocity_tau`` the velocity forgets itself and the
    position diffuses (variance ≈ q τ/β²): a fix minutes after the last says nothing about
    a velocity to extrapolate. The constant-velocity model instead reads a displacement d
    over a long τ as a constant acceleration and ends with a velocity of ~2d/τ, which it
    then extrapolates (measured on duty-cycled collars: kilometres).
    """
    tau = np.asarray(tau, dtype=float)
    var = float(accel_std) ** 2
    q = np.zeros(tau.shape + (4, 4))
    if velocity_tau and velocity_tau > 0:
        tau = np.maximum(tau, 0.0)
        beta = 1.0 / float(velocity_tau)
        a = -np.expm1(-beta * tau)                 # 1 − e^{−βτ}
        b = -np.expm1(-2.0 * beta * tau)           # 1 − e^{−2βτ}
        vv = var / (2.0 * beta) * b
        pv = var / (2.0 * beta ** 2) * a ** 2
        pp = var / beta ** 2 * (tau - 2.0 * a / beta + b / (2.0 * beta))
        pp = np.maximum(pp, 0.0)
    else:
        pp, pv, vv = var * tau ** 4 / 4.0, var * tau ** 3 / 2.0, var * tau ** 2
    for i in (0, 1):
        q[..., i, i] = pp
        q[..., i, i + 2] = pv
        q[..., i + 2, i] = pv
        q[..., i + 2, i + 2] = vv
    return q


def predict_state(x, P, tau, accel_std, velocity_tau: float = 0.0):
    """Prediction ``x⁻ = F x``, ``P⁻ = F P Fᵀ + Q`` over ``tau`` seconds (the motion model
    of :func:`transition` / :func:`process_noise`).

    Vectorized: ``x`` (..., 4), ``P`` (..., 4, 4), ``tau`` (...) broadcast together; the
    herd clock uses it to carry filter states to the ticks.
    """
    f = transition(tau, velocity_tau)
    x = np.asarray(x, dtype=float)
    P = np.asarray(P, dtype=float)
    xp = np.einsum('...ij,...j->...i', f, x)
    Pp = (np.einsum('...ij,...jk,...lk->...il', f, P, f)
          + process_noise(tau, accel_std, velocity_tau))
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


@dataclass
class _Candidate:
    """A chain of mutually consistent fixes the track did not accept (see the module
    docstring): ``fixes`` [(t, z, R)], ``jump`` = it began with a fix beyond the envelope,
    or has a fix far outside the collar's range."""

    fixes: list
    jump: bool


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
        candidates: the open candidate tracks (at most :attr:`MAX_CANDIDATES`).
        range_moments: [n, Σx, Σy, Σx², Σxy, Σy²] of the accepted states (the collar's
            range, :func:`outside_range`).
        left_place: where the track was before it last moved to a reachable chain (the
            hypothesis that the chain was a burst; module docstring), or None.
        left_recent: where it was before a later fix taken by the walk component alone,
            while ``left_place`` is still held (module docstring), or None.
    """

    #: open candidate chains kept at once (the oldest is dropped)
    MAX_CANDIDATES = 4

    def __init__(self, params: FilterParams | None = None, **overrides):
        if params is None:
            params = FilterParams(**overrides)
        elif overrides:
            params = FilterParams(**{**params.__dict__, **overrides})
        self.params = params
        self._gate = params.gate_threshold
        self._gate_sigma = float(np.sqrt(self._gate))
        self._v0 = params.initial_velocity_std or params.max_speed
        from filterpy.kalman import KalmanFilter   # (imports scipy.stats: 0.8 s; lazily)
        self.kf = KalmanFilter(dim_x=4, dim_z=2)
        self.kf.H = _H.copy()
        self.t = float('nan')
        self.counters = {name: 0 for name in COUNTERS}
        self.last_report = float('nan')
        self.candidates: list[_Candidate] = []
        self._ever_initialised = False
        self._last_position_fix = -np.inf     # stamp of the last fix with a position
        self.range_moments = np.zeros(6)      # [n, Σx, Σy, Σx², Σxy, Σy²] of accepted states
        self.left_place: LeftPlace | None = None
        self.left_recent: LeftPlace | None = None

    # -- state ----------------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        """Whether the filter has a track (a first fix accepted)."""
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
        x, P = predict_state(self.x, self.P, float(t) - self.t, self.params.accel_std,
                             self.params.velocity_tau)
        return CollarState(float(t), x, P)

    def is_stale(self, t: float) -> bool:
        """No accepted fix for more than ``stale_after`` seconds before ``t`` (or never)."""
        return not self.initialised or float(t) - self.t > self.params.stale_after

    # -- one fix --------------------------------------------------------------------------
    def update(self, stamp: float, east: float, north: float, *, status: int = 0,
               position_covariance=None, position_covariance_type: int = 0) -> FixResult:
        """Process one fix (stamp in s of data time, east/north in m about the datum)."""
        result = self._update(stamp, east, north, status, position_covariance,
                              position_covariance_type)
        if result.accepted:                  # the state joins the collar's range
            e, n = self.x[0], self.x[1]
            self.range_moments += (1.0, e, n, e * e, e * n, n * n)
        return result

    def _far(self, z) -> bool:
        """The fix is far outside the collar's range (:func:`outside_range`)."""
        p = self.params
        return outside_range(self.range_moments, z, p.range_sigmas, p.range_margin,
                             p.range_min_fixes)

    def _at_track_place(self, dist: float, sigma: float) -> bool:
        """The track itself lies far outside the collar's range (a move there was
        confirmed) and the fix, ``dist`` m from it (``sigma`` the std of that distance), is
        within ``range_margin`` beyond 3 σ of it: the place the track is at counts as part
        of the range (module docstring, *far outside the collar's range*)."""
        return (dist - 3.0 * sigma <= self.params.range_margin
                and self._far(self.x[:2]))

    def _update(self, stamp, east, north, status, position_covariance,
                position_covariance_type) -> FixResult:
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
        latest = self.t if self.initialised else -np.inf
        for cand in self.candidates:
            latest = max(latest, cand.fixes[-1][0])
        if stamp <= latest:
            return self._reject('time', f'stamp {stamp:.3f} is not after the last fix '
                                        f'{latest:.3f} (time going backwards or a duplicate)')
        z = np.array([float(east), float(north)])
        r = measurement_covariance(position_covariance, position_covariance_type,
                                   p.default_position_std, p.position_std_floor)
        silence = stamp - self._last_position_fix
        self._last_position_fix = stamp
        if self.initialised and silence > p.reinit_after_gap:
            self._lose_track()
        if not self.initialised:
            return self._lost_fix(stamp, z, r)

        tau = stamp - self.t
        # speed envelope against the last accepted filtered position
        dist = float(np.hypot(*(z - self.x[:2])))
        sigma = float(np.sqrt(np.linalg.eigvalsh(r + self.P[:2, :2])[-1]))
        allowed = float(p.reach(tau)) + self._gate_sigma * sigma
        if dist > allowed:
            # beyond reach of the track, but maybe not of where it was before it last
            # moved: then the fix may be the animal back from a burst the track followed
            left = self.left_place
            jump = left is None or not left.for_chain or not left.reaches(
                stamp, z, r, p, self._gate_sigma)
            return self._candidate_fix(stamp, z, r, 'speed', jump,
                                       f'{dist:.1f} m in {tau:.3g} s is beyond reach '
                                       f'(allowed {allowed:.1f} m)')
        # Mahalanobis distance of the innovation
        F = transition(tau, p.velocity_tau)
        Q = process_noise(tau, p.accel_std, p.velocity_tau)
        x_pred = F @ self.x
        P_pred = F @ self.P @ F.T + Q
        y = z - x_pred[:2]
        d2 = float(y @ np.linalg.solve(P_pred[:2, :2] + r, y))
        gate_d2 = d2
        walk = None
        if p.walk is not None:
            # the walk component of the motion mixture (FilterParams.walk)
            Fw = transition(tau, p.walk[1])
            Qw = process_noise(tau, p.walk[0], p.walk[1])
            xw = Fw @ self.x
            Pw = Fw @ self.P @ Fw.T + Qw
            yw = z - xw[:2]
            rw = r + (p.walk_position_std or 0.0) ** 2 * np.eye(2)
            Sw = Pw[:2, :2] + rw
            d2w = float(yw @ np.linalg.solve(Sw, yw))
            walk = (xw, Pw, Sw, d2w, rw)
            gate_d2 = min(d2, d2w)          # an outlier under both components
        # a fix that continues an open chain better than it fits the track belongs to the
        # chain: a burst cannot make itself plausible by lasting long enough for the
        # track's envelope and gate to grow
        far = self._far(z) and not self._at_track_place(dist, sigma)
        for cand in reversed(self.candidates):
            if (self._consistent(cand, stamp, z, r)
                    and self._chain_distance(cand, z) < np.hypot(*y)):
                reason = 'range' if far else ('speed' if cand.jump else 'gate')
                return self._candidate_fix(stamp, z, r, reason, cand.jump,
                                           'continues a chain of rejected fixes',
                                           d2=d2, chain=cand)
        if far:
            return self._candidate_fix(stamp, z, r, 'range', True,
                                       f'{dist:.0f} m from the track, far outside the range '
                                       f'the collar has kept', d2=d2)
        if gate_d2 > self._gate:
            return self._candidate_fix(stamp, z, r, 'gate', False,
                                       f'Mahalanobis distance² {gate_d2:.1f} exceeds the '
                                       f'{p.gate_probability:g} gate {self._gate:.2f}', d2=d2)
        if walk is None:
            self.kf.predict(F=F, Q=Q)
            self.kf.update(z, R=r)
        else:
            if d2 > self._gate:
                # taken by the walk component alone: a move the track may have to undo;
                # a place already held is kept, and this one beside it
                if self.left_place is None:
                    self.left_place = self._place_here(for_chain=False)
                else:
                    self.left_recent = self._place_here(for_chain=False)
            self._mixture_update(z, r, x_pred, P_pred, P_pred[:2, :2] + r, d2, *walk)
        self.t = stamp
        self.candidates.clear()
        self.counters['accepted'] += 1
        self._held()
        return FixResult(True, 'accepted', '', d2)

    # -- internals ------------------------------------------------------------------------
    def _mixture_update(self, z, r, xg, Pg, Sg, d2g, xw, Pw, Sw, d2w, rw):
        """GPB1 step of the graze/walk mixture (FilterParams.walk): each component's
        Kalman update (Joseph form, as filterpy), weights ∝ π_j N(y_j; 0, S_j), the mixture
        collapsed to its mean and covariance (Bar-Shalom, Li & Kirubarajan 2001,
        eq. 11.6.6-7)."""
        pw = self.params.walk_probability
        lw = ((math.log(pw) - 0.5 * math.log(np.linalg.det(Sw)) - 0.5 * d2w)
              - (math.log1p(-pw) - 0.5 * math.log(np.linalg.det(Sg)) - 0.5 * d2g))
        ww = 1.0 / (1.0 + math.exp(-lw)) if lw > -700.0 else 0.0
        parts = []
        H = np.zeros((2, 4))
        H[0, 0] = H[1, 1] = 1.0
        for x, P, S, R in ((xg, Pg, Sg, r), (xw, Pw, Sw, rw)):
            K = P @ H.T @ np.linalg.inv(S)
            A = np.eye(4) - K @ H
            parts.append((x + K @ (z - x[:2]), A @ P @ A.T + K @ R @ K.T))
        w = (1.0 - ww, ww)
        x = w[0] * parts[0][0] + w[1] * parts[1][0]
        P = sum(wj * (Pj + np.outer(xj - x, xj - x)) for wj, (xj, Pj) in zip(w, parts))
        self.kf.x = x.reshape(4, 1)
        self.kf.P = P


    def _initialise(self, stamp, z, r):
        self.kf.x = np.array([[z[0]], [z[1]], [0.0], [0.0]])
        P = np.zeros((4, 4))
        P[:2, :2] = r
        P[2, 2] = P[3, 3] = self._v0 ** 2
        self.kf.P = P
        self.t = stamp

    def _lose_track(self):
        """No accepted fix for ``reinit_after_gap``: the old state means nothing any more."""
        self.t = float('nan')
        self.candidates.clear()
        self._forget_places()

    def _forget_places(self):
        self.left_place = self.left_recent = None

    def _held(self):
        """An accepted fix at the track's place: one fewer for each place it left (each
        dropped at zero: the new place has held, no burst)."""
        for name in ('left_place', 'left_recent'):
            place = getattr(self, name)
            if place is not None:
                place.fixes_left -= 1
                if place.fixes_left <= 0:
                    setattr(self, name, None)

    def _reject(self, reason, detail, d2=float('nan')):
        self.counters[f'rejected_{reason}'] += 1
        return FixResult(False, reason, detail, d2)

    def _reach_ratio(self, cand: _Candidate, stamp, z, r) -> float:
        """Distance of the fix from the chain's fixes over the reach allowed in the time
        between them, the smallest over the chain's fixes (≤ 1: the fix continues the chain;
        inf if not after its last fix)."""
        if not stamp > cand.fixes[-1][0]:
            return float('inf')
        best = float('inf')
        for t_prev, z_prev, r_prev in cand.fixes:
            sigma = float(np.sqrt(np.linalg.eigvalsh(r + r_prev)[-1]))
            allowed = float(self.params.reach(stamp - t_prev)) + self._gate_sigma * sigma
            best = min(best, float(np.hypot(*(z - z_prev))) / allowed)
        return best

    @staticmethod
    def _chain_distance(cand: _Candidate, z) -> float:
        """Distance (m) of ``z`` from the nearest fix of the chain."""
        return float(min(np.hypot(*(z - z_prev)) for _, z_prev, _ in cand.fixes))

    def _consistent(self, cand: _Candidate, stamp, z, r) -> bool:
        """The fix continues ``cand``: within reach of one of its fixes."""
        return self._reach_ratio(cand, stamp, z, r) <= 1.0

    def _attach(self, stamp, z, r, jump: bool, chain=None, near: bool = False
                ) -> _Candidate:
        """Append the fix to ``chain``, to the newest consistent candidate, or to a new one
        (``near``: a fix inside the collar's range, which joins no chain that began with a
        jump)."""
        if chain is None:
            chain = next((c for c in reversed(self.candidates)
                          if self._consistent(c, stamp, z, r) and not (near and c.jump)),
                         None)
        if chain is None:
            chain = _Candidate([], jump)
            self.candidates.append(chain)
            del self.candidates[:-self.MAX_CANDIDATES]
        chain.fixes.append((stamp, z, r))
        return chain

    def _lost_fix(self, stamp, z, r) -> FixResult:
        """A fix while there is no track: confirm a chain of ``confirm_fixes_lost`` fixes."""
        far = self._far(z)
        chain = self._attach(stamp, z, r, jump=far, near=not far)
        chain.jump |= far           # a chain with a fix far outside the range is a jump
        need = int(self.params.reacquire_fixes if chain.jump
                   else self.params.confirm_fixes_lost)
        if len(chain.fixes) < need:
            self.counters['rejected_unconfirmed'] += 1
            return FixResult(False, 'unconfirmed', f'track lost or not started: waiting for '
                             f'{need} consistent fixes ({len(chain.fixes)} so far)')
        first = not self._ever_initialised
        self._forget_places()
        self._adopt(chain)
        if first:
            return FixResult(True, 'accepted', f'track started on {need} consistent fixes')
        self.counters['reinitialised'] += 1
        return FixResult(True, 'reinitialised', f'track re-acquired on {need} consistent '
                         f'fixes after a gap')

    def _candidate_fix(self, stamp, z, r, reason, jump, detail, d2=float('nan'), chain=None
                       ) -> FixResult:
        """Reject a fix the track refuses, and switch to its candidate chain once it is
        confirmed (see the module docstring)."""
        chain = self._attach(stamp, z, r, jump, chain)
        if reason == 'range':
            chain.jump = True       # a chain with a fix far outside the range is a jump
        need = int(self.params.reacquire_fixes if chain.jump else self.params.confirm_fixes)
        if len(chain.fixes) < need:
            if self._return_to_left(stamp, z, r):
                return FixResult(True, 'reinitialised', 'back at the place the track left: '
                                 'the track returned to it', d2)
            return self._reject(reason, detail, d2)
        self.left_recent = None
        self.left_place = None if chain.jump else self._place_here(for_chain=True)
        self._adopt(chain)
        self.counters['reinitialised'] += 1
        kind = 'beyond reach or far outside its range' if chain.jump else 'outside the gate'
        return FixResult(True, 'reinitialised', f'{need} consistent fixes {kind}: the track '
                         f'moved to them', d2)

    def _place_here(self, for_chain: bool) -> LeftPlace:
        """Where the track is now, kept as the place it leaves (:class:`LeftPlace`)."""
        return LeftPlace(self.t, self.x[:2].copy(), self.P[:2, :2].copy(),
                         int(self.params.reacquire_fixes), for_chain)

    def _return_to_left(self, stamp, z, r) -> bool:
        """A fix the track refuses that lies inside the gate of a place it left (the later
        of the two held first; module docstring: *the place the track left*): the track
        goes back there at once (True)."""
        places = [q for q in (self.left_place, self.left_recent) if q is not None]
        places.sort(key=lambda q: -q.t)
        return any(self._return_to(q, stamp, z, r) for q in places)

    def _return_to(self, left: LeftPlace, stamp, z, r) -> bool:
        """A refused fix inside the gate of the place ``left`` (its position and
        covariance, velocity 0, predicted to the fix with the collar's own motion model):
        the move was a burst, and the track goes back at once, updated with this fix."""
        p = self.params
        x0 = np.array([left.z[0], left.z[1], 0.0, 0.0])
        P0 = np.zeros((4, 4))
        P0[:2, :2] = left.r
        tau = stamp - left.t
        F = transition(tau, p.velocity_tau)
        xp = F @ x0
        Pp = F @ P0 @ F.T + process_noise(tau, p.accel_std, p.velocity_tau)
        y = z - xp[:2]
        if float(y @ np.linalg.solve(Pp[:2, :2] + r, y)) > self._gate:
            return False
        self.kf.x = xp.reshape(4, 1)
        self.kf.P = Pp
        self.kf.update(z, R=r)
        self.t = stamp
        self.candidates.clear()
        self._forget_places()
        self.counters['accepted'] += 1
        self.counters['reinitialised'] += 1
        return True

    def _adopt(self, chain: _Candidate):
        """Re-initialise on the chain's first fix and update through the rest; a fix
        outside the gate of that track starts it afresh (module docstring: the chain's
        fixes span a move the collar's own model cannot follow)."""
        fixes = list(chain.fixes)
        self._initialise(*fixes[0])
        for t_k, z_k, r_k in fixes[1:]:
            x_pred, P_pred = predict_state(self.x, self.P, t_k - self.t,
                                           self.params.accel_std, self.params.velocity_tau)
            y = z_k - x_pred[:2]
            if float(y @ np.linalg.solve(P_pred[:2, :2] + r_k, y)) > self._gate:
                self._initialise(t_k, z_k, r_k)
                continue
            self.kf.x = x_pred.reshape(4, 1)
            self.kf.P = P_pred
            self.kf.update(z_k, R=r_k)
            self.t = t_k
        self.candidates.clear()
        self._ever_initialised = True
        # the earlier fixes of the chain stay counted as rejected; this one is accepted
        self.counters['accepted'] += 1
