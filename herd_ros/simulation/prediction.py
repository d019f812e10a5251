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

from herd_ros.model.herd_model import HerdModel
from herd_ros.trajectory import HerdTrajectory

METHODS = ('model', 'constant_velocity', 'stay_put')


def _rms(err: np.ndarray, axis=None) -> np.ndarray:
    """RMS of the Euclidean errors (..., 2), over the finite ones (a missing agent or
    neighbour leaves NaN: not a prediction, not counted)."""
    sq = (err ** 2).sum(-1)
    with np.errstate(invalid='ignore'):
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
               max_starts: int = 2000) -> dict[str, dict[int, float]]:
    """{method: {k: herd RMS (m)}} of k-step-ahead prediction from many start steps.

    All start steps of a run are simulated together (the model is vectorized over a leading
    axis), at most ``max_starts`` evenly spaced starts per run.
    """
    kmax = max(ks)
    sums = {m: {k: 0.0 for k in ks} for m in METHODS}
    counts = {k: 0 for k in ks}
    for r in runs:
        p = _aligned(model, r)
        T = p.shape[0]
        if T < kmax + 2:
            continue
        starts = np.arange(0, T - kmax - 1)
        if len(starts) > max_starts:
            starts = starts[np.linspace(0, len(starts) - 1, max_starts).astype(int)]
        pos = p[starts + 1].copy()               # p^{τ+1}
        vel = (p[starts + 1] - p[starts]) / model.dt  # u^τ
        anchor, anchor_v = pos.copy(), vel.copy()
        # u^{τ+1} = a u^τ + drift(p^τ); p^{τ+2} = p^{τ+1} + Δt u^{τ+1}
        prev = p[starts].copy()
        for step in range(1, kmax + 1):
            vel_next = model.next_velocity(vel, prev)
            prev = pos
            pos = pos + model.dt * vel_next
            vel = vel_next
            if step in counts:
                truth = p[starts + 1 + step]
                sums['model'][step] += float(((pos - truth) ** 2).sum(-1).sum())
                cv = anchor + step * model.dt * anchor_v
                sums['constant_velocity'][step] += float(((cv - truth) ** 2).sum(-1).sum())
                sums['stay_put'][step] += float(((anchor - truth) ** 2).sum(-1).sum())
                counts[step] += truth.shape[0] * truth.shape[1]
    return {m: {k: float(np.sqrt(sums[m][k] / counts[k])) if counts[k] else float('nan')
                for k in ks} for m in METHODS}


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
                               from_fraction: float = 0.5) -> dict:
    """One-step skill of predictions as a live estimator published them, next to baselines.

    ``predictions.positions[k]`` is the position predicted for time ``predictions.times[k]``
    (a herd-clock tick). Over the ticks t in the last ``1 − from_fraction`` of ``herd``'s
    span where the truth p(t), p(t − Δt), p(t − 2Δt) and the prediction are all finite:

    * model: the published prediction;
    * constant velocity: p(t − Δt) + (p(t − Δt) − p(t − 2Δt));
    * stay-put: p(t − Δt);
    * damping only: p(t − Δt) + a_i (p(t − Δt) − p(t − 2Δt)), a_i fitted by
      :func:`damping_only_fit` on the herd before the evaluated part (held out).

    Returns {method: RMS (m)} plus ``samples`` (agent-ticks) and ``from_time``.
    """
    times = np.asarray(herd.times, dtype=float)
    index = {round(t / dt): k for k, t in enumerate(times)}
    t_split = times[0] + from_fraction * (times[-1] - times[0]) if len(times) else np.nan
    p = herd.positions
    a = damping_only_fit(p[times < t_split]) if len(times) else np.zeros(p.shape[1])
    errs = {m: [] for m in ('model', 'constant_velocity', 'stay_put', 'damping_only')}
    for t, pred in zip(predictions.times, predictions.positions):
        if t < t_split:
            continue
        k0, k1, k2 = (index.get(round(t / dt) - j) for j in (0, 1, 2))
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
