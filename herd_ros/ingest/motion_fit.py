"""Each collar's movement model, fitted by maximum likelihood of its Kalman innovations.

The collar filter's motion model (:func:`herd_ros.ingest.collar_filter.process_noise`) is
the integrated Ornstein-Uhlenbeck velocity process: per axis ``dv = −v/τ_v dt + σ_a dW``,
``dp = v dt`` — the continuous-time correlated random walk of crawl (Johnson, London, Lea &
Durban 2008, Ecology 89:1208) and the IOU model of ctmm (Fleming et al. 2014, Am. Nat.
183:E154; Calabrese, Fleming & Gurarie 2016, MEE 7:1124), discretised exactly for any
interval. Its two limits are the random walk (τ_v → 0 with the diffusion held) and the
constant velocity (τ_v → ∞). Two numbers describe it for the fit:

* ``τ_v`` (s), how long the animal keeps its velocity;
* ``D`` (m²/s per axis), its long-run diffusion: ``Var p(t+τ) − p(t) → D τ`` for τ ≫ τ_v,
  so ``σ_a = √D / τ_v`` and the stationary speed std per axis is ``√(D / (2 τ_v))``.

and, for fixes without a covariance (``COVARIANCE_TYPE_UNKNOWN``), the measurement std
``σ_m`` (m per axis). Fixes with a covariance keep theirs (its mean variance per axis).

**Likelihood** (Harvey 1989, *Forecasting, structural time series models and the Kalman
filter*, §3.4, the prediction-error decomposition)::

    ℓ(θ) = Σ_k [ −log(2π S_k) − ‖y_k‖² / (2 S_k) ]        (2 axes, isotropic)

with ``y_k`` the innovation and ``S_k`` its variance per axis. The axes are independent
(isotropic model and measurement), so one covariance recursion serves both. A heavy tail
replaces the Gaussian term beyond ``HUBER_NIS`` (χ²₂ 0.99): ``‖y‖²/S`` is taken as
``2√(c ‖y‖²/S) − c`` there (Huber 1964), so a stray fix costs linearly, not quadratically,
and cannot drag the fit.

**Search**: Nelder & Mead (1965) on log τ_v, log D (, log σ_m²), compiled, each collar
from the least-squares fit of its variogram (:func:`moment_start`); where the compiled
kernels are absent, a grid with coordinate refinement, vectorised over collars. The
random walk (τ_v a tenth of the collar's shortest typical interval: its velocity forgets
itself between fixes) and the IOU (τ_v free) are fitted separately. The IOU is chosen
only where it is both the likelier model by AIC (Akaike 1974: it needs one parameter
more) and the closer one-step predictor on the same fixes beyond chance
(:func:`one_step_distances`, the distance from each fix to where the filter, run
causally, predicted it: a prequential check, Dawid 1984, J. R. Stat. Soc. A 147:278;
:func:`significantly_closer`, the Diebold-Mariano test on those distances, paired fix by
fix). The two disagree on real GPS collars, whose error is correlated over minutes: a
persistent velocity describes the wandering fixes well, and carried forward it misses
the next one (measured on 39 cattle tracks from GPS loggers fixing every 30-60 s, not in
the repository: doc/gps_ingest.md). Closer by a few per cent on a window, the IOU still
carried a velocity the walk component had taken from one far fix into the next
minutes, and lost the tail there; it must now be closer beyond the window's noise.

**Prior**: a collar with fewer than ``min_fixes`` usable fixes takes the pooled fit of all
collars (their likelihoods summed over the same grid); if none has enough, the caller's
default model.

Plain numpy; no ROS. Used by the offline ingest (:func:`herd_ros.ingest.pipeline
.trajectory_from_fixes`) and the ``gps_ingest`` node on a running window of each collar's
accepted fixes.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

#: squared-Mahalanobis (χ², 2 dof) beyond which an innovation costs linearly (p = 0.99)
HUBER_NIS = -2.0 * math.log(0.01)
#: the model names of :class:`MotionFit`
MODELS = ('rw', 'iou', 'prior')
#: largest velocity persistence searched (s): two days, the constant-velocity end
TAU_MAX = 2 * 86400.0
#: Nelder-Mead's budget (likelihood evaluations) for (random walk, IOU), from the grid
COLD_EVALS = (80, 120)
#: ... and from the same model's previous optimum (a refit, :attr:`MotionFit.optima`)
WARM_EVALS = (40, 80)
#: Nelder-Mead stops when its simplex's log-likelihoods agree within this (0.1 or more
#: leaves a fit short of the best point of a dense grid; τ_v wanders where ℓ is flat in it)
NM_FTOL = 0.05


@dataclass(frozen=True)
class MotionFit:
    """The fitted motion model of one collar.

    Attributes:
        model: ``'rw'`` (random walk), ``'iou'`` (correlated velocity) or ``'prior'``
            (too few fixes: the pooled or default model).
        velocity_tau: τ_v (s).
        diffusion: D (m²/s per axis).
        position_std: σ_m (m per axis) for fixes without a covariance; NaN if every fix of
            the collar carried one.
        loglik: ℓ at the optimum (NaN for a prior).
        aic: ``2k − 2ℓ`` (NaN for a prior).
        n_fixes: fixes the fit used.
        optima: the search's optimum of each model, ``(random walk, IOU)``, each
            ``(log10 τ_v, log10 σ_a, log10 σ_m²)``: where a refit on the collar's next
            window starts (None for a prior).
        hdop: the std of a fix without a covariance is ``position_std`` × its HDOP (the
            likelier of that and one std for all, :func:`fit_motion`), where it has one.
    """

    model: str
    velocity_tau: float
    diffusion: float
    position_std: float
    loglik: float
    aic: float
    n_fixes: int
    optima: tuple | None = None
    hdop: bool = False

    @property
    def accel_std(self) -> float:
        """σ_a (m/s²) of the filter's process noise: ``√D / τ_v``."""
        return math.sqrt(self.diffusion) / self.velocity_tau

    @property
    def speed_std(self) -> float:
        """Stationary velocity std per axis (m/s): ``√(D / (2 τ_v))``; NaN for a fit at the
        constant-velocity end (τ_v at :data:`TAU_MAX`): the window showed no end to the
        velocity's persistence, so it says nothing of a stationary speed (√(D/2τ_v) there
        reads tens of m/s for a walking baboon)."""
        if self.velocity_tau >= (1.0 - 1e-6) * TAU_MAX:
            return float('nan')
        return math.sqrt(self.diffusion / (2.0 * self.velocity_tau))


def iou_discretisation(tau, velocity_tau, accel_std):
    """The exact discretisation of the 1-D IOU over an interval ``tau`` (arrays broadcast):
    ``(f_pv, f_vv, q_pp, q_pv, q_vv)`` with ``F = [[1, f_pv], [0, f_vv]]`` and ``Q`` as
    :func:`herd_ros.ingest.collar_filter.process_noise` (β = 1/τ_v)::

        f_pv = (1 − e^{−βτ})/β,  f_vv = e^{−βτ},
        q_vv = σ²/(2β) (1 − e^{−2βτ}),  q_pv = σ²/(2β²) (1 − e^{−βτ})²,
        q_pp = σ²/β² (τ − 2(1 − e^{−βτ})/β + (1 − e^{−2βτ})/(2β))
    """
    tau = np.maximum(np.asarray(tau, dtype=float), 0.0)
    beta = 1.0 / np.asarray(velocity_tau, dtype=float)
    var = np.asarray(accel_std, dtype=float) ** 2
    a = -np.expm1(-beta * tau)
    b = -np.expm1(-2.0 * beta * tau)
    f_pv = a / beta
    f_vv = np.exp(-beta * tau)
    q_vv = var / (2.0 * beta) * b
    q_pv = var / (2.0 * beta ** 2) * a ** 2
    q_pp = np.maximum(var / beta ** 2 * (tau - 2.0 * a / beta + b / (2.0 * beta)), 0.0)
    return f_pv, f_vv, q_pp, q_pv, q_vv


def innovation_loglik(t, z, r, n, velocity_tau, diffusion, position_var, walk=None):
    """ℓ (module docstring) of N collars at G parameter points each: the compiled loop
    (:func:`herd_ros.ingest.collar_kernels.motion_loglik`) where the collar kernels are,
    else :func:`innovation_loglik_numpy` (same arguments, same numbers to rounding)."""
    return _filter_pass(t, z, r, n, velocity_tau, diffusion, position_var, walk, False)


def one_step_distances(t, z, r, n, velocity_tau, diffusion, position_var, walk=None):
    """One-step prediction distances (m) of N collars at G parameter points each: the
    filter of :func:`innovation_loglik` run over each collar's fixes, and at each fix
    after the first the distance from the fix to where its own model predicted it (what
    the track says just before the fix). The compiled loop
    (:func:`herd_ros.ingest.collar_kernels.motion_distance`) where the collar kernels
    are, else :func:`innovation_loglik_numpy` (``distance=True``). Arguments as
    :func:`innovation_loglik_numpy`; returns (N, G, K), NaN at each collar's first fix
    and beyond its ``n``."""
    return _filter_pass(t, z, r, n, velocity_tau, diffusion, position_var, walk, True)


def one_step_distance(t, z, r, n, velocity_tau, diffusion, position_var, walk=None):
    """Mean of :func:`one_step_distances` over each collar's fixes after its first
    (N, G)."""
    d = one_step_distances(t, z, r, n, velocity_tau, diffusion, position_var, walk)
    return np.nansum(d, axis=-1) / np.maximum(np.asarray(n) - 1, 1)[:, None]


#: one-sided level of :func:`significantly_closer` (z of a 5 % test)
CLOSER_Z = 1.645


def significantly_closer(d_new, d_old, z: float = CLOSER_Z) -> np.ndarray:
    """Per collar, whether predictor "new" is the closer one-step predictor beyond chance:
    the Diebold-Mariano test of equal predictive accuracy (Diebold & Mariano 1995, J. Bus.
    Econ. Stat. 13:253) on the paired distances ``d_new``, ``d_old`` (N, K; NaN where
    none), one-sided: the mean of ``d_new − d_old`` below −``z`` of its standard error
    (one-step forecasts: no autocorrelation terms)."""
    diff = np.asarray(d_new, float) - np.asarray(d_old, float)
    ok = np.isfinite(diff)
    m = ok.sum(axis=1)
    d = np.where(ok, diff, 0.0)
    mean = d.sum(axis=1) / np.maximum(m, 1)
    var = np.where(ok, (d - mean[:, None]) ** 2, 0.0).sum(axis=1) / np.maximum(m - 1, 1)
    with np.errstate(invalid='ignore', divide='ignore'):
        stat = mean / np.sqrt(var / np.maximum(m, 1))
    return (m >= 2) & (mean < 0) & ((var == 0) | (stat < -float(z)))


def _filter_pass(t, z, r, n, velocity_tau, diffusion, position_var, walk, distance):
    """:func:`innovation_loglik` (``distance`` False) or :func:`one_step_distance`."""
    from herd_ros.ingest import collar_bank
    if not collar_bank.AVAILABLE:
        return innovation_loglik_numpy(t, z, r, n, velocity_tau, diffusion, position_var,
                                       walk, distance=distance)
    shape = np.broadcast_shapes(np.shape(velocity_tau), np.shape(diffusion),
                                np.shape(position_var))

    def arr(x, s=shape):
        return np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=float), s))

    out = np.empty(shape + (np.shape(t)[1],) if distance else shape)
    wa, wt, pw, wr2 = _walk(walk)
    args = (arr(t, np.shape(t)), arr(z, np.shape(z)), arr(r, np.shape(r)),
            np.ascontiguousarray(n, dtype=np.int64), arr(velocity_tau), arr(diffusion),
            arr(position_var), float(wa), float(wt), float(pw), float(wr2))
    if distance:
        collar_bank.KERNELS.motion_distance(*args, out)
    else:
        collar_bank.KERNELS.motion_loglik(*args, HUBER_NIS, out)
    return out


def _walk(walk):
    """(σ_a, τ_v, π, added variance) of a walk component given as 3 or 4 numbers, or the
    'none' values for the kernels."""
    if walk is None:
        return 0.0, 1.0, 0.5, 0.0
    w = tuple(float(v) for v in walk)
    return w if len(w) == 4 else w + (0.0,)


def fix_var(r, sm2):
    """A fix's variance in the likelihood: ``r`` where known (≥ 0), ``sm2 · (−r)`` for a
    fix scaled by its HDOP (``r`` = −HDOP², :func:`herd_ros.ingest.motion_refit
    .fix_variance`), ``sm2`` where unknown (NaN); broadcast together."""
    r = np.asarray(r, float)
    with np.errstate(invalid='ignore'):
        return np.where(r >= 0, r, np.where(r < 0, np.asarray(sm2) * -r, sm2))


def innovation_loglik_numpy(t, z, r, n, velocity_tau, diffusion, position_var,
                            walk=None, distance: bool = False):
    """ℓ (module docstring) of N collars at G parameter points each, vectorised over
    collars and points (the reference of the compiled loop).

    Args:
        t: (N, K) fix times (s), increasing along K over the first ``n`` entries.
        z: (N, K, 2) positions (m).
        r: (N, K) measurement variance per axis (m²); NaN = unknown (``position_var``).
        n: (N,) fixes of each collar (entries beyond are padding).
        velocity_tau, diffusion, position_var: (N, G) the parameter points.
        walk: None, or ``(accel_std, velocity_tau, probability[, added variance])`` of the
            filter's walk component (:attr:`~herd_ros.ingest.collar_filter.FilterParams.walk`,
            ``walk_position_std²``): the
            likelihood is then that of the graze/walk mixture the filter runs (GPB1: each
            step's density ``(1 − π) N(y; S_g) + π N(y; S_w)``, the posterior collapsed
            per axis), so the fit describes the animal between its walks.

        distance: return instead the distance (m) from each fix to the own model's
            prediction of it (:func:`one_step_distances`): (N, G, K), NaN at each
            collar's first fix and beyond its ``n``.

    Returns:
        (N, G) log-likelihoods (the first fix of a collar initialises, it is not scored).
    """
    N, K = t.shape
    tv = np.asarray(velocity_tau, float)
    D = np.asarray(diffusion, float)
    sm2 = np.asarray(position_var, float)
    accel = np.sqrt(D) / tv
    r0 = fix_var(r[:, :1], sm2)
    shape = tv.shape + (2,)                       # (N, G, axis)
    p = np.broadcast_to(z[:, None, 0, :], shape).copy()
    v = np.zeros(shape)
    a = np.broadcast_to(r0[..., None], shape).copy()
    b = np.zeros(shape)
    c = np.broadcast_to((D / (2.0 * tv))[..., None], shape).copy()
    ll = np.zeros(tv.shape)
    steps = np.full(tv.shape + (K,), np.nan)
    comps = [(tv, accel, 0.0, 0.0)]
    if walk is not None:
        wa, wt, pw, wr2 = _walk(walk)
        comps = [(tv, accel, math.log1p(-pw), 0.0),
                 (np.full(tv.shape, float(wt)), np.full(tv.shape, float(wa)), math.log(pw),
                  wr2)]
    for k in range(1, K):
        live = (k < n)[:, None]
        if not live.any():
            break
        dt = np.where(live, (t[:, k] - t[:, k - 1])[:, None], 0.0)
        rk = fix_var(r[:, k:k + 1], sm2)[..., None]
        zk = z[:, None, k, :]
        out = []
        for j, (ctv, cacc, logp, extra) in enumerate(comps):
            f, g, qpp, qpv, qvv = (q[..., None] for q in iou_discretisation(dt, ctv, cacc))
            ap = a + 2.0 * f * b + f * f * c + qpp
            bp = g * (b + f * c) + qpv
            cp = g * g * c + qvv
            S = ap + rk + extra
            y = zk - (p + f * v)
            if distance and j == 0:             # the own model: what the track says
                steps[..., k] = np.where(live, np.sqrt((y * y).sum(axis=-1)), np.nan)
            nis = y * y / S
            if walk is None:
                tot = nis.sum(axis=-1)
                nis_sum = np.where(tot > HUBER_NIS,
                                   2.0 * np.sqrt(HUBER_NIS * tot) - HUBER_NIS, tot)
            else:
                nis_sum = nis.sum(axis=-1)
            lc = logp - np.log(2.0 * math.pi) - 0.5 * np.log(S).sum(axis=-1) - 0.5 * nis_sum
            kp = ap / S
            kv = bp / S
            out.append((lc, p + f * v + kp * y, g * v + kv * y, ap - ap * ap / S,
                        bp - ap * bp / S, cp - bp * bp / S))
        if len(out) == 1:
            lk, pn, vn, an, bn, cn = out[0]
        else:
            l0, l1 = out[0][0], out[1][0]
            lk = np.logaddexp(l0, l1)
            w1 = np.exp(l1 - lk)[..., None]
            w0 = 1.0 - w1
            (_, p0, v0, a0, b0, c0), (_, p1, v1, a1, b1, c1) = out
            pn = w0 * p0 + w1 * p1
            vn = w0 * v0 + w1 * v1
            an = w0 * (a0 + (p0 - pn) ** 2) + w1 * (a1 + (p1 - pn) ** 2)
            bn = w0 * (b0 + (p0 - pn) * (v0 - vn)) + w1 * (b1 + (p1 - pn) * (v1 - vn))
            cn = w0 * (c0 + (v0 - vn) ** 2) + w1 * (c1 + (v1 - vn) ** 2)
        ll += np.where(live, lk, 0.0)
        l3 = live[..., None]
        p = np.where(l3, pn, p)
        v = np.where(l3, vn, v)
        a = np.where(l3, an, a)
        b = np.where(l3, bn, b)
        c = np.where(l3, cn, c)
    if distance:
        return steps
    return ll


def _pack(tracks, max_fixes):
    """(t, z, r, n) padded arrays of the collars' last ``max_fixes`` fixes each."""
    N = len(tracks)
    K = max(2, max((min(len(tr[0]), max_fixes) for tr in tracks), default=2))
    t = np.zeros((N, K))
    z = np.zeros((N, K, 2))
    r = np.full((N, K), np.nan)
    n = np.zeros(N, np.int64)
    for i, (ti, zi, ri) in enumerate(tracks):
        m = min(len(ti), max_fixes)
        t[i, :m] = ti[len(ti) - m:]
        z[i, :m] = zi[len(ti) - m:]
        r[i, :m] = ri[len(ti) - m:]
        n[i] = m
        t[i, m:] = t[i, m - 1] if m else 0.0
    return t, z, r, n


def _search(t, z, r, n, log_tv, log_D, log_sm, fit_tv, fit_sm, walk, levels=4,
            sweeps=2):  # noqa: C901
    """Maximise ℓ per collar: the best point of the product grid (log τ_v × log D ×
    log σ_m², each (N, ·)), then coordinate refinement: at each level, ``sweeps`` passes
    over the free coordinates, each trying the best point ± 1, 2 steps along one
    coordinate (the step halves at each level, starting at the grid's). Correlated
    parameters (D and σ_m trade off) are followed by the repeated sweeps. Returns the best
    (log τ_v, log D, log σ_m², ℓ), each (N,). τ_v stays within the grid's range."""
    N = len(n)
    lt, lD, ls = log_tv, log_D, log_sm                    # (N, a), (N, b), (N, c)
    A, B, C = lt.shape[1], lD.shape[1], ls.shape[1]
    grid = np.stack([np.repeat(lt, B * C, axis=1),
                     np.tile(np.repeat(lD, C, axis=1), (1, A)),
                     np.tile(ls, (1, A * B))], axis=-1)   # (N, G, 3)

    def loglik(pts):
        return innovation_loglik(t, z, r, n, 10.0 ** pts[..., 0], 10.0 ** pts[..., 1],
                                 10.0 ** pts[..., 2], walk)

    ll = loglik(grid)
    rows = np.arange(N)
    k = np.argmax(ll, axis=1)
    best, best_ll = grid[rows, k], ll[rows, k]
    step = np.array([(g[0, -1] - g[0, 0]) / max(g.shape[1] - 1, 1) for g in (lt, lD, ls)])
    free = [d for d, on in enumerate((fit_tv, True, fit_sm)) if on]
    offsets = np.array([-2.0, -1.0, 1.0, 2.0])
    for _ in range(levels):
        step = step / 2.0
        for _ in range(sweeps):
            for d in free:
                pts = np.repeat(best[:, None, :], len(offsets), axis=1)
                pts[..., d] += offsets[None, :] * step[d]
                if d == 0:
                    pts[..., 0] = np.clip(pts[..., 0], lt[:, :1], lt[:, -1:])
                ll = loglik(pts)
                k = np.argmax(ll, axis=1)
                better = ll[rows, k] > best_ll
                best[better] = pts[rows, k][better]
                best_ll[better] = ll[rows, k][better]
    return best[:, 0], best[:, 1], best[:, 2], best_ll


def fit_motion(tracks, *, min_fixes: int = 20, max_fixes: int = 200,
               position_std_floor: float = 0.5, default: MotionFit | None = None,
               walk=None, start=None) -> list[MotionFit]:
    """Fit each collar's motion model (module docstring; arguments as
    :func:`fit_motion_once`). A collar whose fixes without a covariance carry an HDOP (its
    ``r`` −HDOP², :func:`herd_ros.ingest.motion_refit.fix_variance`) is fitted twice: those
    fixes' std σ_m × HDOP (σ_m the UERE of ctmm's error model, Fleming et al. 2020,
    *Methods Ecol. Evol.* 12) and one σ_m for all; the likelier is kept (the same number of
    parameters) if it is also the closer one-step predictor on the window (by the mean,
    :func:`one_step_distance`; the IOU, a parameter more, must be closer beyond chance),
    and :attr:`MotionFit.hdop` says which."""
    kw = dict(min_fixes=min_fixes, max_fixes=max_fixes,
              position_std_floor=position_std_floor, default=default, walk=walk)
    tracks = list(tracks)
    with np.errstate(invalid='ignore'):
        scaled = [bool((np.asarray(r, float)[-max_fixes:] < 0).any()) for _, _, r in tracks]
    if not any(scaled):
        return fit_motion_once(tracks, start=start, **kw)
    plain = [(t, z, np.where(np.asarray(r, float) < 0, np.nan, r)) if s else (t, z, r)
             for (t, z, r), s in zip(tracks, scaled)]
    fits = fit_motion_once(tracks, start=start, **kw)
    idx = [i for i, s in enumerate(scaled) if s]
    alt = fit_motion_once([plain[i] for i in idx],
                          start=None if start is None else [start[i] for i in idx], **kw)
    out = list(fits)
    likelier = [(i, f0) for i, f0 in zip(idx, alt)
                if fits[i].model != 'prior' and fits[i].loglik >= f0.loglik]
    for i, f0 in zip(idx, alt):
        out[i] = f0
    if likelier:
        # as for the IOU: the HDOP's model must also be the closer one-step predictor
        ii = [i for i, _ in likelier]
        d_h = _window_distance([tracks[i] for i in ii], [fits[i] for i in ii], max_fixes,
                               walk)
        d_0 = _window_distance([plain[i] for i in ii], [f0 for _, f0 in likelier],
                               max_fixes, walk)
        for k, i in enumerate(ii):
            if d_h[k] < d_0[k]:
                out[i] = dataclasses.replace(fits[i], hdop=True)
    return out


def _clean(track):
    """A track's (t, z, r) with its rows of a non-finite time or position, and those not
    after the one before, dropped."""
    ti, zi, ri = track
    ti = np.asarray(ti, float)
    zi = np.asarray(zi, float).reshape(-1, 2)
    ri = np.asarray(ri, float).reshape(-1)
    ok = np.isfinite(ti) & np.isfinite(zi).all(axis=1)
    ti, zi, ri = ti[ok], zi[ok], ri[ok]
    keep = np.concatenate([[True], np.diff(ti) > 0]) if len(ti) else ok[:0]
    return ti[keep], zi[keep], ri[keep]


def _window_distance(tracks, fits, max_fixes, walk) -> np.ndarray:
    """:func:`one_step_distance` of each fit on its own track's window (the fixes it
    was fitted on)."""
    t, z, r, n = _pack([_clean(tr) for tr in tracks], max_fixes)
    col = lambda v: np.asarray(v, float)[:, None]                       # noqa: E731
    tv = col([f.velocity_tau for f in fits])
    D = col([f.diffusion for f in fits])
    sm2 = col([f.position_std ** 2 for f in fits])     # fitted: the windows have unknowns
    return one_step_distance(t, z, r, n, tv, D, sm2, walk)[:, 0]


def fit_motion_once(tracks, *, min_fixes: int = 20, max_fixes: int = 200,
                    position_std_floor: float = 0.5, default: MotionFit | None = None,
                    walk=None, start=None) -> list[MotionFit]:
    """Fit each collar's motion model (module docstring), the variances ``r`` as given.

    Args:
        tracks: per collar ``(t (K,), z (K, 2), r (K,))``: the times (s, increasing),
            positions (m) and measurement variances per axis (m², NaN = unknown) of its
            accepted fixes (outliers already out).
        min_fixes: fewer usable fixes take the pooled fit (the prior).
        max_fixes: the fit uses each collar's last ``max_fixes`` fixes (a running window).
        position_std_floor: the smallest σ_m searched (m).
        default: the model of a collar when no collar has ``min_fixes`` (None = a random
            walk of D = 0.05 m²/s with σ_m = 5 m).
        walk: ``(accel_std, velocity_tau, probability)`` of the filter's walk component, or
            None (see :func:`innovation_loglik`).
        start: per track, a previous :class:`MotionFit` to start the search from (a
            refit on a running window), or None (searched afresh).

    Returns:
        One :class:`MotionFit` per track, in order.
    """
    if default is None:
        default = MotionFit('prior', 1.0, 0.05, 5.0, float('nan'), float('nan'), 0)
    cleaned = [_clean(tr) for tr in tracks]
    enough = [i for i, tr in enumerate(cleaned) if len(tr[0]) >= min_fixes]
    out = [None] * len(cleaned)
    if not enough:
        return [default] * len(cleaned)
    t, z, r, n = _pack([cleaned[i] for i in enough], max_fixes)
    N = len(enough)
    with np.errstate(invalid='ignore'):
        unknown = ~(r >= 0) & (np.arange(t.shape[1])[None, :] < n[:, None])
    sm_free = unknown.any(axis=1)         # per collar: some fixes without a covariance
    fit_sm = bool(sm_free.any())
    # the random-walk limit: τ_v a tenth of the collar's 10th-percentile interval
    tv_rw = np.maximum(0.05, 0.1 * interval_percentile(t, n, 10.0))
    floor2 = float(position_std_floor) ** 2
    from herd_ros.ingest import collar_bank
    if collar_bank.AVAILABLE:
        prev = [None] * N if start is None else [start[i] for i in enough]
        rw, iou = _nelder_mead_fits(t, z, r, n, tv_rw, sm_free, floor2, walk, prev)
    else:
        ls0 = np.tile(np.log10(floor2) + np.linspace(0.0, 6.5, 7), (N, 1))
        if not fit_sm:
            ls0 = ls0[:, :1]
        lD0 = np.tile(np.linspace(-4.0, 1.5, 7), (N, 1))
        # random walk: τ_v fixed
        rw = _search(t, z, r, n, np.log10(tv_rw)[:, None], lD0, ls0, False, fit_sm,
                     walk) + (None,)
        # IOU: τ_v free from 3 × the random-walk value to two days
        lt0 = np.linspace(np.log10(3.0 * tv_rw), np.full(N, np.log10(TAU_MAX)), 6).T
        iou = _search(t, z, r, n, lt0, lD0, ls0, True, fit_sm, walk) + (None,)
    k_extra = sm_free.astype(float)
    aic_rw = 2.0 * (1 + k_extra) - 2.0 * rw[3]
    aic_iou = 2.0 * (2 + k_extra) - 2.0 * iou[3]
    # where AIC prefers the IOU, it must also be the closer one-step predictor, beyond
    # chance (significantly_closer)
    better = aic_iou < aic_rw
    if better.any():
        b = np.flatnonzero(better)
        dist = one_step_distances(t[b], z[b], r[b], n[b],
                                  *(10.0 ** np.stack([rw[d][b], iou[d][b]], axis=1)
                                    for d in range(3)), walk)
        better[b] = significantly_closer(dist[:, 1], dist[:, 0])
    for j, i in enumerate(enough):
        pick, name, aic = (iou, 'iou', aic_iou[j]) if better[j] else (rw, 'rw', aic_rw[j])
        has_unknown = bool(unknown[j, :n[j]].any())
        optima = None if rw[4] is None else (tuple(rw[4][j]), tuple(iou[4][j]))
        out[i] = MotionFit(name, float(10.0 ** pick[0][j]), float(10.0 ** pick[1][j]),
                           float(math.sqrt(10.0 ** pick[2][j])) if has_unknown else
                           float('nan'), float(pick[3][j]), float(aic), int(n[j]), optima)
    if len(enough) < len(cleaned):
        pooled = _pooled(t, z, r, n, tv_rw, fit_sm, floor2, walk)
        for i in range(len(cleaned)):
            if out[i] is None:
                out[i] = pooled
    return out


def interval_percentile(t, n, q: float) -> np.ndarray:
    """Per collar, the ``q``-th percentile of its intervals ``diff(t[j, :n[j]])`` (numpy's
    default linear interpolation), for all collars at once (t (N, K) padded, n (N,) ≥ 2)."""
    t = np.asarray(t, float)
    n = np.asarray(n, np.int64)
    m = np.maximum(n - 1, 1)
    d = np.diff(t, axis=1)
    d = np.where(np.arange(d.shape[1])[None, :] < (n - 1)[:, None], d, np.inf)
    d.sort(axis=1)
    h = (m - 1) * (q / 100.0)
    lo = np.floor(h).astype(np.int64)
    hi = np.minimum(lo + 1, m - 1)
    rows = np.arange(len(n))
    a, b = d[rows, lo], d[rows, hi]
    return a + (h - lo) * np.where(hi > lo, b - a, 0.0)


def moment_start(t, z, r, n, floor2):
    """Starting values (D, σ_m²) per collar from the variogram of consecutive fixes: per
    axis ``E |Δz|²/2 = D Δt + 2 σ_m²`` for a random walk seen with white noise, fitted by
    least squares over each collar's pairs (then kept within sane bounds); the 2 × 2 normal
    equations of all collars at once."""
    n = np.asarray(n, np.int64)
    N = len(n)
    dt = np.diff(t, axis=1)
    valid = np.arange(dt.shape[1])[None, :] < (n - 1)[:, None]
    y = np.where(valid, 0.25 * (np.diff(z, axis=1) ** 2).sum(axis=2), 0.0)  # per axis, halved
    x = np.where(valid, dt, 0.0)
    w = valid.astype(float)
    # minimise Σ (D x + 2 s − y)²: [[Σx², 2Σx], [2Σx, 4Σ1]] (D, s) = (Σxy, 2Σy); each sum
    # taken in order over the collar's own pairs, so that it does not depend on how far
    # its row is padded (numpy's unrolled sums group the terms by the row's length): a
    # collar's fit is the same whichever collars it is fitted with
    last = np.maximum(n - 2, 0)
    rows = np.arange(N)

    def total(a):
        return np.cumsum(a, axis=1)[rows, last] if a.shape[1] else np.zeros(N)
    sxx, sx, s1 = total(x * x), total(x), total(w)
    sxy, sy = total(x * y), total(y)
    det = 4.0 * (sxx * s1 - sx * sx)
    with np.errstate(invalid='ignore', divide='ignore'):
        D = (4.0 * s1 * sxy - 4.0 * sx * sy) / det
        s2 = (2.0 * sxx * sy - 2.0 * sx * sxy) / det
    ok = (n >= 3) & np.isfinite(D) & np.isfinite(s2) & (np.abs(det) > 1e-12 * (sxx * s1 + 1.0))
    D = np.where(ok, np.clip(np.nan_to_num(D), 1e-5, 1e3), 0.05)
    s2 = np.where(ok, np.clip(np.nan_to_num(s2), floor2, 1e4), max(floor2, 1.0))
    return D.reshape(N), s2.reshape(N)


def _nelder_mead_fits(t, z, r, n, tv_rw, sm_free, floor2, walk, prev, scout: int = 60):
    """The random walk and the IOU of every collar, each as (log τ_v, log D, log σ_m², ℓ):
    a coarse grid on each collar's first ``scout`` fixes finds the basin (σ_m² about the
    variogram's value, :func:`moment_start`), then the compiled Nelder-Mead
    (:func:`herd_ros.ingest.collar_kernels.motion_nelder_mead`) polishes on the whole
    window. Searched in log (τ_v, σ_a, σ_m²), σ_a the acceleration std (the diffusion
    D = σ_a² τ_v² runs off to infinity at the constant-velocity end; σ_a does not). A
    collar with a previous fit (``prev``, a refit on its running window) starts each
    model's search from that model's previous optimum (:attr:`MotionFit.optima`), with
    smaller steps and a shorter budget (:data:`WARM_EVALS`). At a first fit the IOU is
    also searched from the random walk just fitted, with τ_v the median interval, and the
    better of its two optima kept: the IOU's likelihood has a basin there that the grid
    misses (on 200 collars seen at 1 s, the ingest benchmark's herd, the grid's start
    alone picked the IOU for 51 where it is the better model for 95). Returns per model
    (log τ_v, log D, log σ_m², ℓ, the optima (N, 3))."""
    from herd_ros.ingest import collar_bank, collar_threads
    N = len(n)
    wa, wt, pw, wr2 = _walk(walk)
    D0, s20 = moment_start(t, z, r, n, floor2)
    short = np.minimum(n, scout)
    # σ_m is searched only for the collars with fixes of unknown covariance (each collar's
    # search is its own: it does not depend on which collars are fitted with it)
    ls = np.log10(s20)[:, None] + np.where(sm_free[:, None], [[-1.0, 0.0, 1.0]], 0.0)
    ls = np.maximum(ls, np.log10(floor2))

    def start_points(lt, la, warm_x):
        """Start per collar: its previous fit's point ``warm_x`` (N, 3; NaN rows: none),
        else the best of the grid log τ (N, a) × log σ_a (N, b) × ls on its first
        ``scout`` fixes; and whether it is the previous fit's."""
        A, B, C = lt.shape[1], la.shape[1], ls.shape[1]
        has = np.isfinite(warm_x).all(axis=1)
        out = warm_x.copy()
        cold = np.flatnonzero(~has)
        if not len(cold):
            return out, has
        lt, la, lsc = lt[cold], la[cold], ls[cold]
        pts = np.stack([np.repeat(lt, B * C, axis=1),
                        np.tile(np.repeat(la, C, axis=1), (1, A)),
                        np.tile(lsc, (1, A * B))], axis=-1)            # (N, G, 3)
        tv = 10.0 ** pts[..., 0]
        ll = innovation_loglik(t[cold], z[cold], r[cold], short[cold], tv,
                               (10.0 ** pts[..., 1] * tv) ** 2, 10.0 ** pts[..., 2], walk)
        k = np.argmax(ll, axis=1)
        out[cold] = pts[np.arange(len(cold)), k]
        return out, has

    def polish(x0, lo, hi, step, evals, rows=slice(None)):
        """Nelder-Mead of the collars ``rows`` from x0 (all (N, ·), evals (N,)), the
        collars split over threads by their work, fixes × evaluations
        (:mod:`~herd_ros.ingest.collar_threads`: the same optimum for each collar)."""
        idx = np.arange(N)[rows]
        x = np.empty((len(idx), 3))
        ll = np.empty(len(idx))

        def part(sl):
            ii = idx[sl]
            return lambda: collar_bank.KERNELS.motion_nelder_mead(
                np.ascontiguousarray(t[ii]), np.ascontiguousarray(z[ii]),
                np.ascontiguousarray(r[ii]), np.ascontiguousarray(n[ii], dtype=np.int64),
                np.ascontiguousarray(x0[ii]), np.ascontiguousarray(lo[ii]),
                np.ascontiguousarray(hi[ii]), np.ascontiguousarray(step[ii], dtype=float),
                float(wa), float(wt), float(pw), float(wr2), HUBER_NIS,
                np.ascontiguousarray(evals[ii], dtype=np.int64), NM_FTOL, x[sl], ll[sl])

        collar_threads.run(part(sl) for sl in collar_threads.split(n[idx] * evals[idx]))
        return x, ll

    def steps(warm, fixed_tv):
        """First steps (N, 3): 0.5 in log10 from the grid, 0.2 from a previous fit; 0 for
        a held coordinate."""
        s0 = np.where(warm, 0.2, 0.5)
        return np.column_stack([np.zeros(N) if fixed_tv else s0, s0,
                                np.where(sm_free, s0, 0.0)])

    sm_lo = np.full(N, np.log10(floor2))
    sm_hi = np.full(N, 4.0)
    # random walk: τ_v fixed; σ_a about the variogram's diffusion (D = σ_a² τ_rw²)
    la_rw = np.log10(np.sqrt(D0) / tv_rw)[:, None] + np.linspace(-1.5, 1.5, 5)[None, :]
    warm_x = np.full((N, 3), np.nan)
    for j, p in enumerate(prev):
        if p is not None and p.optima is not None:
            warm_x[j] = (np.log10(tv_rw[j]),) + tuple(p.optima[0][1:])
        elif p is not None and p.model == 'rw':
            s2 = p.position_std ** 2 if np.isfinite(p.position_std) else s20[j]
            warm_x[j] = (np.log10(tv_rw[j]), np.log10(math.sqrt(p.diffusion) / tv_rw[j]),
                         np.log10(max(s2, floor2)))
    x0, warm = start_points(np.log10(tv_rw)[:, None], la_rw, warm_x)
    lo = np.column_stack([np.log10(tv_rw), np.full(N, -8.0), sm_lo])
    hi = np.column_stack([np.log10(tv_rw), np.full(N, 4.0), sm_hi])
    xr, llr = polish(x0, lo, hi, steps(warm, True),
                     np.where(warm, WARM_EVALS[0], COLD_EVALS[0]))
    # IOU: τ_v from 3 × the random-walk value to two days
    lt = np.linspace(np.log10(3.0 * tv_rw), np.full(N, np.log10(TAU_MAX)), 5).T
    la = np.tile(np.linspace(-5.0, 0.0, 6), (N, 1))
    warm_x = np.full((N, 3), np.nan)
    for j, p in enumerate(prev):
        if p is not None and p.optima is not None:
            warm_x[j] = p.optima[1]
        elif p is not None and p.model == 'iou':
            s2 = p.position_std ** 2 if np.isfinite(p.position_std) else s20[j]
            warm_x[j] = (np.log10(p.velocity_tau), np.log10(p.accel_std),
                         np.log10(max(s2, floor2)))
    x0, warm = start_points(lt, la, warm_x)
    lo_i = np.column_stack([np.log10(3.0 * tv_rw), np.full(N, -8.0), sm_lo])
    hi_i = np.column_stack([np.full(N, np.log10(TAU_MAX)), np.full(N, 2.0), sm_hi])
    xi, lli = polish(x0, lo_i, hi_i, steps(warm, False),
                     np.where(warm, WARM_EVALS[1], COLD_EVALS[1]))
    # a first fit also from the random walk just fitted (τ_v the median interval, the
    # same long-run diffusion and fix std): the IOU's likelihood has a basin there the
    # grid misses; a refit follows the better one from its previous optimum
    c = np.flatnonzero(~warm)
    if len(c):
        med = interval_percentile(t[c], n[c], 50.0)
        tau = np.clip(med, 3.0 * tv_rw[c], TAU_MAX)
        x1 = x0.copy()
        x1[c] = np.column_stack([np.log10(tau), xr[c, 1] + np.log10(tv_rw[c] / tau),
                                 xr[c, 2]])
        xi2, lli2 = polish(x1, lo_i, hi_i, steps(np.ones(N, bool), False),
                           np.full(N, WARM_EVALS[1]), rows=c)
        better = lli2 > lli[c]
        xi[c[better]] = xi2[better]
        lli[c[better]] = lli2[better]

    def as_d(x):
        return 2.0 * (x[:, 1] + x[:, 0])          # log10 D = 2 (log σ_a + log τ_v)

    return ((xr[:, 0], as_d(xr), xr[:, 2], llr, xr), (xi[:, 0], as_d(xi), xi[:, 2], lli, xi))


def _pooled(t, z, r, n, tv_rw, fit_sm, floor2, walk) -> MotionFit:
    """The prior: one random walk for all collars (likelihoods summed over a shared grid)."""
    N = len(n)
    tv = float(np.median(tv_rw))
    lD = np.linspace(-4.0, 1.5, 23)
    ls = np.log10(floor2) + np.linspace(0.0, 6.5, 27) if fit_sm else np.array([0.0])
    DD = np.tile(np.repeat(lD, len(ls)), (N, 1))
    SM = np.tile(np.tile(ls, len(lD)), (N, 1))
    ll = innovation_loglik(t, z, r, n, np.full(DD.shape, tv), 10.0 ** DD,
                           10.0 ** SM, walk).sum(axis=0)
    g = int(np.argmax(ll))
    return MotionFit('prior', tv, float(10.0 ** DD[0, g]),
                     float(math.sqrt(10.0 ** SM[0, g])) if fit_sm else float('nan'),
                     float('nan'), float('nan'), 0)
