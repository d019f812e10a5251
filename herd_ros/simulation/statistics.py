"""Herd statistics compared between real and simulated herds (Schwager et al. 2007, Fig. 6).

Per agent i, over all steps τ and all other agents j:
    mean_distance, std_distance — mean and standard deviation of ‖p_j^τ − p_i^τ‖;
    mean_speed, std_speed       — mean and standard deviation of ‖p_i^{τ+1} − p_i^τ‖/Δt,
                                  over consecutive steps of the clock only (gaps skipped).
"""
from __future__ import annotations

import numpy as np

from herd_ros.trajectory import HerdTrajectory

STATISTICS = ('mean_distance', 'std_distance', 'mean_speed', 'std_speed')


def herd_statistics(runs: list[HerdTrajectory] | HerdTrajectory) -> dict[str, dict[str, float]]:
    """{agent: {mean_distance, std_distance, mean_speed, std_speed}} pooled over runs."""
    if isinstance(runs, HerdTrajectory):
        runs = [runs]
    agents = list(runs[0].agents)
    dists = {a: [] for a in agents}
    speeds = {a: [] for a in agents}
    for r in runs:
        p = r.positions[:, [r.agents.index(a) for a in agents]]
        d = np.sqrt(((p[:, None, :, :] - p[:, :, None, :]) ** 2).sum(-1))  # (T, N, N)
        # speeds only between consecutive steps of the clock (a recording with gaps must
        # not turn a missing stretch into one fast step)
        steps = np.diff(r.times)
        dt = float(np.min(steps)) if len(steps) else 1.0
        regular = np.abs(steps - dt) <= 1e-6 * max(dt, 1.0)
        v = np.sqrt((np.diff(p, axis=0) ** 2).sum(-1))[regular] / dt
        for i, a in enumerate(agents):
            dists[a].append(np.delete(d[:, i, :], i, axis=1).ravel())
            speeds[a].append(v[:, i])
    out = {}
    for a in agents:
        dd = np.concatenate(dists[a])
        ss = np.concatenate(speeds[a])
        dd = dd[np.isfinite(dd)]
        ss = ss[np.isfinite(ss)]
        # an agent absent from every run (a collar that never reported in that part of
        # the data) has no statistics: NaN, without numpy's empty-slice warnings
        out[a] = {'mean_distance': _or_nan(dd, np.mean), 'std_distance': _or_nan(dd, np.std),
                  'mean_speed': _or_nan(ss, np.mean), 'std_speed': _or_nan(ss, np.std)}
    return out


def _or_nan(values: np.ndarray, stat) -> float:
    return float(stat(values)) if len(values) else float('nan')


def relative_differences(reference: dict, other: dict) -> dict[str, dict[str, float]]:
    """|other − reference| / |reference| per agent and statistic (agents present in both)."""
    return {a: {k: abs(other[a][k] - reference[a][k]) / max(abs(reference[a][k]), 1e-12)
                for k in STATISTICS} for a in reference if a in other}
