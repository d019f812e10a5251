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
    return np.sqrt((err ** 2).sum(-1).mean(axis=axis))


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
