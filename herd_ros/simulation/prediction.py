"""Prediction accuracy of a herd model next to naive baselines, on held-out data.

One step (eq. 8): p̂^{τ+2} = p^{τ+1} + Δt (a u^τ + Σ f + g), against
    constant velocity: p̂^{τ+2} = p^{τ+1} + Δt u^τ     (a = 1, no forces)
    stay-put:          p̂^{τ+2} = p^{τ+1}.

k steps: from p^{τ}, p^{τ+1} the model is run forward deterministically (w = 0) for k steps
and compared with p^{τ+1+k}; constant velocity extrapolates p^{τ+1} + k Δt u^τ; stay-put
keeps p^{τ+1}. Errors are Euclidean position errors (m); RMS over agents and start steps.
"""
from __future__ import annotations

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.model.herd_model import HerdModel
from herd_ros.model.velocity_memory import remember
from herd_ros.nan_stats import empty_slices_quiet
from herd_ros.trajectory import HerdTrajectory

METHODS = ('model', 'constant_velocity', 'stay_put')


def _rms(err: np.ndarray, axis=None) -> np.ndarray:
    """RMS of the Euclidean errors (..., 2), over the finite ones (a missing agent or
    neighbour leaves NaN: not a prediction, not counted)."""
    sq = (err ** 2).sum(-1)
    with empty_slices_quiet():
        return np.sqrt(np.nanmean(sq, axis=axis))


def one_step_errors(model: HerdModel, positions: np.ndarray) -> dict[str, np.ndarray]:
    """Position errors (T−2, N, 2) of each method for one run (columns in model order)."""
    p = np.asarray(positions, dtype=float)
    u = np.diff(p, axis=0) / model.dt
    truth = p[2:]
    return {'model': model.predict_one_step(p) - truth,
            'constant_velocity': p[1:-1] + model.dt * u[:-1] - truth,
            'stay_put': p[1:-1] - truth}


def _aligned(model: HerdModel, run: HerdTrajectory) -> np.ndarray:
    return run.positions[:, [run.agents.index(a) for a in model.agents]]


def one_step_rms(model: HerdModel, runs: list[HerdTrajectory]) -> dict[str, dict[str, float]]:
    """{method: {agent: RMS (m), 'herd': RMS}} of one-step prediction over ``runs``."""
    errs = {m: [] for m in METHODS}
    for r in runs:
        if r.n_steps < 3:
            continue
        for m, e in one_step_errors(model, _aligned(model, r)).items():
            errs[m].append(e)
    out = {}
    for m in METHODS:
        e = np.concatenate(errs[m])
        per_agent = _rms(e, axis=0)
        out[m] = {a: float(v) for a, v in zip(model.agents, per_agent)}
        out[m]['herd'] = float(_rms(e))
    return out


def k_step_rms(model: HerdModel, runs: list[HerdTrajectory], ks=(1, 5, 10, 30),
               max_starts: int = 2000, damping=None) -> dict[str, dict[int, float]]:
    """{method: {k: herd RMS (m)}} of k-step-ahead prediction from many start steps.

    All start steps of a run are simulated together (the model is vectorized over a leading
    axis), at most ``max_starts`` evenly spaced starts per run. With ``damping`` (N,) the
    damping-only model p̂^{s+k} = p^s + (a + … + a^k)(p^s − p^{s−1}) is scored too
    (``'damping_only'``). Every method is counted on the same starts and agents: where all of
    them have a prediction and the truth is there.
    """
    kmax = max(ks)
    methods = METHODS + (('damping_only',) if damping is not None else ())
    sums = {m: {k: 0.0 for k in ks} for m in methods}
    counts = {k: 0 for k in ks}
    a = None if damping is None else np.asarray(damping, dtype=float)[:, None]
    kappa = model.velocity_memory
    for r in runs:
        p = _aligned(model, r)
        T = p.shape[0]
        if T < kmax + 2:
            continue
        starts = np.arange(0, T - kmax - 1)
        if len(starts) > max_starts:
            starts = starts[np.linspace(0, len(starts) - 1, max_starts).astype(int)]
        pos = p[starts + 1].copy()               # p^{τ+1}
        anchor_v = (p[starts + 1] - p[starts]) / model.dt  # u^τ
        anchor = pos.copy()
        vel = model.memory_velocities(p)[1][starts]        # ū^τ (u^τ at κ = 1)
        gain = np.zeros_like(a) if a is not None else None
        # u^{τ+1} = a ū^τ + drift(p^τ); p^{τ+2} = p^{τ+1} + Δt u^{τ+1}
        prev = p[starts].copy()
        for step in range(1, kmax + 1):
            vel_next = model.next_velocity(vel, prev)
            prev = pos
            pos = pos + model.dt * vel_next
            vel = remember(kappa, vel, vel_next)
            if a is not None:
                gain = gain + a ** step
            if step in counts:
                truth = p[starts + 1 + step]
                preds = [('model', pos), ('constant_velocity', anchor + step * model.dt * anchor_v),
                         ('stay_put', anchor)]
                if a is not None:
                    preds.append(('damping_only', anchor + gain * model.dt * anchor_v))
                sq = {m: ((x - truth) ** 2).sum(-1) for m, x in preds}
                # a missing agent or neighbour leaves NaN: counted only where every method
                # has a prediction and the truth is there
                ok = np.logical_and.reduce([np.isfinite(v) for v in sq.values()])
                for m in methods:
                    sums[m][step] += float(sq[m][ok].sum())
                counts[step] += int(ok.sum())
    return {m: {k: float(np.sqrt(sums[m][k] / counts[k])) if counts[k] else float('nan')
                for k in ks} for m in methods}


def naive_ahead(positions: np.ndarray, k: int = 1) -> dict[str, np.ndarray]:
    """The naive k-step predictions aligned as :func:`predict_ahead`'s (p̂[t] from p[t−k]
    and p[t−k−1]; NaN for t < k + 1 or where an agent is missing): stay-put p[t−k] and
    constant velocity p[t−k] + k (p[t−k] − p[t−k−1]). {name: (T, N, 2)}."""
    p = np.asarray(positions, dtype=float)
    T = p.shape[0]
    stay, cv = np.full(p.shape, np.nan), np.full(p.shape, np.nan)
    if T >= k + 2:
        origin, before = p[1:T - k], p[:T - k - 1]
        stay[k + 1:] = origin
        cv[k + 1:] = origin + k * (origin - before)
    return {'stay_put': stay, 'constant_velocity': cv}


def last_raw_fix_ahead(run: HerdTrajectory, agents, k: int = 1) -> np.ndarray | None:
    """For GPS input (``run.meta['raw_fixes']``: per agent its fixes' times and ENU
    positions), p̂[t] = the agent's last raw fix at or before the origin tick t − k: what a
    user has with no filter, aligned as :func:`predict_ahead`'s (NaN before the agent's
    first fix). None for a run with no raw fixes (a trajectory file)."""
    raw = run.meta.get('raw_fixes')
    if raw is None:
        return None
    T = run.n_steps
    out = np.full((T, len(agents), 2), np.nan)
    if T < k + 2:
        return out
    origins = np.asarray(run.times, dtype=float)[1:T - k]
    for i, a in enumerate(agents):
        t, xy = raw.get(a, (np.zeros(0), np.zeros((0, 2))))
        j = np.searchsorted(np.asarray(t, dtype=float), origins, side='right') - 1
        have = j >= 0
        out[k + 1:][have, i] = np.asarray(xy, dtype=float)[j[have]]
    return out


def damping_only_fit(positions: np.ndarray) -> np.ndarray:
    """Per-agent damping a of p̂^{τ+2} = p^{τ+1} + a (p^{τ+1} − p^τ), least squares over the
    finite triples of ``positions`` (T, N, 2): a_i = Σ u^τ·u^{τ+1} / Σ |u^τ|² (NaN skipped).
    The simplest model the herd model nests (no interactions, no field)."""
    p = np.asarray(positions, dtype=float)
    u = np.diff(p, axis=0)
    num = np.nansum((u[:-1] * u[1:]).sum(-1), axis=0)
    den = np.nansum((u[:-1] * u[:-1]).sum(-1) * np.isfinite(u[1:]).all(-1), axis=0)
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(den > 0, num / den, 0.0)


def published_prediction_skill(herd: HerdTrajectory, predictions: HerdTrajectory, dt: float,
                               from_fraction: float = 0.5, clock: float | None = None) -> dict:
    """One-step skill of predictions as a live estimator published them, next to baselines.

    ``predictions.positions[k]`` is the position predicted for time ``predictions.times[k]``
    (a herd-clock tick). Over the ticks t in the last ``1 − from_fraction`` of ``herd``'s
    span where the truth p(t), p(t − Δt), p(t − 2Δt) and the prediction are all finite:

    * model: the published prediction;
    * constant velocity: p(t − Δt) + (p(t − Δt) − p(t − 2Δt));
    * stay-put: p(t − Δt);
    * damping only: p(t − Δt) + a_i (p(t − Δt) − p(t − 2Δt)), a_i fitted by
      :func:`damping_only_fit` on the herd before the evaluated part (held out).

    ``clock``: the herd's step when it is finer than the model's ``dt`` (a divisor of it;
    default ``dt``); the baselines then look ``dt`` back all the same.

    Returns {method: RMS (m)} plus ``samples`` (agent-ticks) and ``from_time``.
    """
    times = np.asarray(herd.times, dtype=float)
    clock = float(dt if clock is None else clock)
    per = max(1, int(round(dt / clock)))                  # herd ticks per model step
    index = {round(t / clock): k for k, t in enumerate(times)}
    t_split = times[0] + from_fraction * (times[-1] - times[0]) if len(times) else np.nan
    p = herd.positions
    a = (damping_only_fit(p[times < t_split][::per]) if len(times)
         else np.zeros(p.shape[1]))
    errs = {m: [] for m in ('model', 'constant_velocity', 'stay_put', 'damping_only')}
    for t, pred in zip(predictions.times, predictions.positions):
        if t < t_split:
            continue
        k0, k1, k2 = (index.get(round(t / clock) - j * per) for j in (0, 1, 2))
        if k0 is None or k1 is None or k2 is None:
            continue
        truth, p1, p2 = p[k0], p[k1], p[k2]
        ok = (np.isfinite(truth).all(-1) & np.isfinite(p1).all(-1) & np.isfinite(p2).all(-1)
              & np.isfinite(pred).all(-1))
        if not ok.any():
            continue
        v = p1 - p2
        errs['model'].append((pred - truth)[ok])
        errs['constant_velocity'].append((p1 + v - truth)[ok])
        errs['stay_put'].append((p1 - truth)[ok])
        errs['damping_only'].append((p1 + a[:, None] * v - truth)[ok])
    out = {m: (float(_rms(np.concatenate(e))) if e else float('nan')) for m, e in errs.items()}
    out['samples'] = int(sum(len(e) for e in errs['model']))
    out['from_time'] = float(t_split)
    return out


#: χ²₂ quantile of the 90 % prediction ellipse.
CHI2_2_90 = 4.605170185988091
#: Half-life (model steps) of the running noise level of :func:`noise_level`.
NOISE_LEVEL_HALFLIFE = 30.0


def prediction_covariance(model, k: int = 1) -> np.ndarray:
    """Covariance (N, 2, 2) (m²) of the k-step-ahead position prediction of every agent, at
    the model's own noise level (multiply by :func:`noise_level` for the level of the data).

    From the origin (p^s, p^{s−1}) the velocity errors obey e_u^{τ+1} = a e_u^τ + w^τ and the
    position p^{τ+1} = p^τ + Δt u^τ, so the error of p̂^{s+k} is Δt Σ_{j<k} c_j w^{s−1+j} with
    c_j = Σ_{m=0}^{k−1−j} h_m, h_m = a^m (with a velocity memory κ < 1, h_m is the response
    of e_u^{τ+m} = a e_ū^{τ+m−1}, e_ū ← (1 − κ) e_ū + κ e_u, to a unit w), and

        Cov = s_i Δt² Σ_{j<k} c_j² Q_i           (Q_i the agent's noise covariance, eq. 2)

    — exact for the damping-only model; for the full model it leaves out how a position
    error changes the interaction and field terms (first order in their gradients, small
    over a few steps). s_i is the model's ``prediction_scale`` (1 if absent; see
    :func:`calibrate_prediction_scale`).
    """
    if k < 1:
        raise HerdInputError(f'--steps must be at least 1, got {k}')
    a = np.asarray(model.damping, dtype=float)                    # (N,)
    kappa = model.velocity_memory
    # h_m: response of u^{τ+m} to a unit w entering u^τ (a^m at κ = 1)
    h = np.empty((len(a), k))
    h[:, 0] = 1.0
    mean = kappa * h[:, 0]                                        # its ū
    for m in range(1, k):
        h[:, m] = a * mean
        mean = (1.0 - kappa) * mean + kappa * h[:, m]
    c = np.cumsum(h, axis=1)[:, ::-1]                             # c_j = Σ_{m≤k−1−j} h_m
    scale = (model.dt ** 2) * (c ** 2).sum(axis=1)                # (N,)
    calibration = (model.meta or {}).get('prediction_scale')
    if calibration is not None:
        scale = scale * np.asarray(calibration, dtype=float)
    return scale[:, None, None] * np.asarray(model.noise_cov, dtype=float)


def _standardised_residuals(model, positions: np.ndarray) -> np.ndarray:
    """m²_t = w_tᵀ Q_i⁻¹ w_t of the one-step residual of every agent at every target step t
    (T, N), NaN where there is none (χ²₂ if the model's noise were right)."""
    p = np.asarray(positions, dtype=float)
    pred = predict_ahead(model, p, 1)
    w = (p - pred) / model.dt
    q_inv = np.linalg.pinv(np.asarray(model.noise_cov, dtype=float))
    return np.einsum('tni,nij,tnj->tn', w, q_inv, w)


def noise_level(model, positions: np.ndarray, k: int = 1,
                halflife: float = NOISE_LEVEL_HALFLIFE, m2: np.ndarray | None = None
                ) -> np.ndarray:
    """Running noise level ℓ (T, N) of every agent, known at the origin of a k-step
    prediction of each target step: an exponentially weighted mean (half-life ``halflife``
    steps) of m²/2 over the one-step residuals up to the origin (1 before any).

    Animals switch between resting and moving, so their noise comes in spells (volatility
    clustering, as in RiskMetrics' EWMA variance, J.P. Morgan 1996): a fixed Q_i is too
    wide while they rest and too narrow while they move. Scaling the covariance by ℓ took
    the 90 % ellipse of the held-out baboons from 80 % to 90 % coverage (measured).
    """
    if m2 is None:                        # (the caller may have them already)
        m2 = _standardised_residuals(model, positions)
    T, N = m2.shape
    lam = 0.5 ** (1.0 / float(halflife))
    level = np.ones((T, N))
    cur = np.ones(N)
    for t in range(T):                    # level[t] uses residuals of targets < t
        level[t] = cur
        x = m2[t]
        ok = np.isfinite(x)
        cur[ok] = lam * cur[ok] + (1.0 - lam) * 0.5 * x[ok]
    if k > 1:                             # the origin of target t is t − k
        shifted = np.ones((T, N))
        shifted[k - 1:] = level[:T - k + 1]
        level = shifted
    return level


def calibrate_prediction_scale(model, runs_positions) -> list[float]:
    """``prediction_scale`` s_i: the factor that makes the 90 % ellipse of s_i ℓ Δt² Q_i
    (ℓ the running :func:`noise_level`) hold 90 % of the agent's one-step residuals on
    ``runs_positions`` (the training data): s_i = q₀.₉(m²/ℓ) / χ²₂(0.9). Real animals'
    residuals are heavy-tailed, so the Gaussian ellipse of Q_i alone is not a 90 % ellipse;
    this calibrates the 90 % level (and that level only). A run longer than
    :data:`CALIBRATION_STEPS` is sampled in 20 evenly spread contiguous windows (a quantile
    needs no more, and the running level forgets within ~100 steps)."""
    z = []
    for p in runs_positions:
        if len(p) < 3:
            continue
        for q in _windows(np.asarray(p, dtype=float), CALIBRATION_STEPS, 20):
            m2 = _standardised_residuals(model, q)
            z.append(m2 / noise_level(model, q, m2=m2))
    if not z:
        return [1.0] * len(model.agents)
    z = np.concatenate(z)
    out = []
    for i in range(z.shape[1]):
        zi = z[:, i][np.isfinite(z[:, i])]
        out.append(float(max(np.quantile(zi, 0.9) / CHI2_2_90, 1e-6)) if len(zi) >= 10
                   else 1.0)
    return out


#: Steps of a run used at most to calibrate the prediction scale.
CALIBRATION_STEPS = 50_000


def _windows(p: np.ndarray, total: int, count: int) -> list[np.ndarray]:
    """The whole run if it has at most ``total`` steps, else ``count`` evenly spread
    contiguous windows of ``total // count`` steps."""
    T = p.shape[0]
    if T <= total:
        return [p]
    size = total // count
    starts = np.linspace(0, T - size, count).astype(int)
    return [p[s:s + size] for s in starts]


def predict_ahead(model, positions: np.ndarray, k: int = 1) -> np.ndarray:
    """k-step-ahead predictions of every agent at every step of a run.

    ``positions`` (T, N, 2) in the model's agent order -> p̂ (T, N, 2): p̂[t] is predicted
    from p[t−k] and p[t−k−1] (and, with a velocity memory κ < 1, the mean velocity ū up to
    them) by iterating the deterministic law (eq. 2), u^{τ+1} = a ū^τ + Σ f(p^τ) + g(p^τ),
    ū^{τ+1} = (1 − κ) ū^τ + κ u^{τ+1}, p^{τ+1} = p^τ + Δt u^τ; NaN for t < k + 1 and
    where the agent is missing at the origin. A neighbour missing at the origin drops out of
    the interaction sum (it stays missing over the k steps).
    """
    if k < 1:
        raise HerdInputError(f'--steps must be at least 1, got {k}')
    p = np.asarray(positions, dtype=float)
    T = p.shape[0]
    out = np.full(p.shape, np.nan)
    if T < k + 2:
        return out
    prev, pos = p[:T - k - 1], p[1:T - k]           # p^{s−1}, p^s for s = 1 … T−k−1
    _, mean_vel = model.memory_velocities(p)
    mean_vel = mean_vel[:T - k - 1]                 # ū^{s−1} (= u^{s−1} at κ = 1)
    kappa = model.velocity_memory
    for _ in range(k):
        vel_next = model.next_velocity(mean_vel, prev)
        prev, pos = pos, pos + model.dt * vel_next
        mean_vel = remember(kappa, mean_vel, vel_next)
    out[k + 1:] = pos
    return out
