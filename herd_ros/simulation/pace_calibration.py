"""Each animal's free-run noise, calibrated so that the law run freely keeps the animal's
pace (issue 30: process noise apart from measurement noise).

The law's noise w_i ~ N(0, Q_i) is estimated from one-step residuals of the track. Those
residuals carry the collar's error as well as the animal's motion: a position error e_τ
enters the velocity as (e_{τ+1} − e_τ)/Δt, which cancels along a path, but the same variance
drawn as fresh white noise each step does not — it integrates. A law simulated with the
residuals' Q therefore wanders faster than its animal (the baboons' law, run freely over its
own training half at 1 s steps, covers 3.3 × the troop's 10-minute displacement).

This module estimates, per animal, the factor s_i on the standard deviation of w_i (on
Q_i, or on every covariance of its noise regimes) with which the free run reproduces the
animal's **pace** (mean displacement over ten minutes, :func:`~herd_ros.simulation.free_run
.shape_and_pace`) on the training data: a method of simulated moments (McFadden 1989,
Econometrica 57:995; Gouriéroux, Monfort & Renault 1993, indirect inference), one moment per
animal, solved by the fixed-point iteration

    s_i ← s_i · (pace_data,i / pace_sim,i)^(1/γ_i)                      (C1)

with common random numbers (the same noise seeds every iteration). For a law with no
position-dependent pull the displacement is proportional to s_i (γ_i = 1, and (C1) is
Newton's step); a pull that bounds the range makes the pace grow more slowly than s_i, and
γ_i is then the secant slope of log pace against log s_i over the last two iterations
(clipped to [0.25, 1.5]):

    γ_i = Δ log pace_sim,i / Δ log s_i                                  (C2)

Two guards keep the calibration from chasing chance. The data are one realisation: a miss
is corrected only when abs(log(pace_data / pace_sim)) exceeds twice the runs' own standard
deviation of log pace over the seeds (× √(1 + 1/seeds), the data's draw counted), and at
least 10 % (C3). And an animal whose pace barely answers its noise (γ_i < 0.3 at the first
step: a law whose field or neighbours set the pace) keeps its noise: the noise cannot set
that pace, and a factor chosen there would only fit chance.

The free runs start from evenly spaced snapshots of every training run
(:func:`segment_starts`), each for at most ``segment_steps`` steps, and the data's pace is
taken over the same segments; each run is seen where the data are
(:func:`~herd_ros.simulation.free_run.observed_like`).

The mean prediction is untouched (one-step skill and the estimator's predictions are the
same); the prediction covariance keeps Q_i (the one-step residuals are what a prediction is
judged against). The factors go with the model (``model.meta['noise_scale']``, the model
file's ``noise_scale``) and scale every free simulation of the law: ``herd-ros simulate``,
the free-run figures, the robots of the controller
(:func:`~herd_ros.model.noise_regimes.noise_for`).

Plain numpy; no ROS.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from herd_ros.nan_stats import empty_slices_quiet
from herd_ros.simulation.free_run import PACE_WINDOW_S, observed_like, shape_and_pace

#: the fixed-point iterations of (C1)
ITERATIONS = 4
#: noise seeds per iteration (the same ones each time)
SEEDS = 3
#: longest free-run segment (steps) and segments per training run
SEGMENT_STEPS = 5000
SEGMENTS = 4
#: the range a factor is kept in
SCALE_RANGE = (0.05, 3.0)
#: a miss of the pace is corrected when |log(data / runs)| exceeds this many standard
#: deviations of the runs' log pace (C3)
SIGNIFICANCE = 2.0
#: nor is a miss below 10 % (three seeds estimate the runs' spread loosely)
MIN_MISS = math.log(1.1)
#: an animal whose pace answers its noise more weakly than this (C2) keeps its noise
MIN_ELASTICITY = 0.3


def segment_starts(n_steps: int, segment_steps: int, segments: int) -> list[int]:
    """Evenly spaced starts of up to ``segments`` segments of ``segment_steps`` steps (or
    the whole run, when shorter) that fit in a run of ``n_steps``."""
    length = min(n_steps, segment_steps)
    last = n_steps - length
    k = max(1, min(segments, 1 + last // max(length // 2, 1)))
    return sorted({int(round(x)) for x in np.linspace(0, last, k)})


def _data_paces(positions, starts, length, dt):
    """The data's pace (S, N) over the segments of one run."""
    return np.array([shape_and_pace(positions[s0:s0 + length], dt)['pace'] for s0 in starts])


def _segment_paces(model, plan, seeds):
    """The simulated pace (seeds, S, N) over the segments of every run of ``plan`` (S in
    all), each run freely from its segment's start; all runs simulated together
    (:func:`~herd_ros.simulation.herd_simulator.simulate_from_each`)."""
    from herd_ros.simulation.herd_simulator import simulate_from_each
    from herd_ros.trajectory import HerdTrajectory
    segments, runs, run_seeds = [], [], []
    for seed in range(seeds):
        for positions, starts, length in plan:
            times = np.arange(len(positions)) * model.dt
            for k, s0 in enumerate(starts):
                seg = positions[s0:s0 + length]
                segments.append(seg)
                runs.append(HerdTrajectory(times[s0:s0 + length], list(model.agents), seg))
                run_seeds.append(seed * 1009 + k)
    sims = simulate_from_each(model, runs, run_seeds)
    paces = []
    for sim, seg, run in zip(sims, segments, runs):
        # the run's segment may start later (the first snapshot with every agent): the
        # simulation covers the segment's end, seen where the data are (observed_like)
        seen, _ = observed_like(sim, seg, run.times)
        paces.append(shape_and_pace(seen, model.dt)['pace'])
    return np.array(paces).reshape(seeds, -1, model.n_agents)


def with_noise_scale(model, scale):
    """A copy of ``model`` whose free-run noise std is multiplied by ``scale`` (N,) per
    agent (``meta['noise_scale']``)."""
    meta = dict(model.meta or {})
    meta['noise_scale'] = np.asarray(scale, dtype=float).copy()
    return dataclasses.replace(model, meta=meta)


def calibrate_noise_scale(model, positions, *, iterations: int = ITERATIONS,
                          seeds: int = SEEDS, segment_steps: int = SEGMENT_STEPS,
                          segments: int = SEGMENTS) -> dict:
    """Per agent, the factor s_i on its noise std that makes the free run keep its pace on
    ``positions`` (a list of (T, N, 2) training runs in ``model.agents`` order), by (C1).

    Returns {'scale' (N,), 'data_pace' (N,), 'sim_pace' (N,) (at the returned scale),
    'uncalibrated_pace' (N,) (at s = 1), 'iterations', 'segments', 'reason' (per agent,
    '' or why it kept its factor: no pace in the data, (C3), (C2))}.
    """
    n = model.n_agents
    plan = []
    for p in positions:
        p = np.asarray(p, dtype=float)
        if len(p) < 8:
            continue
        length = min(len(p), int(segment_steps))
        plan.append((p, segment_starts(len(p), length, segments), length))
    scale = np.ones(n)
    base = (model.meta or {}).get('noise_scale')
    if base is not None:
        scale = np.asarray(base, dtype=float).copy()
    reason = [''] * n
    if not plan:
        return {'scale': scale, 'data_pace': np.full(n, np.nan),
                'sim_pace': np.full(n, np.nan), 'uncalibrated_pace': np.full(n, np.nan),
                'iterations': 0, 'segments': 0, 'reason': ['no run long enough'] * n}

    def paces(s):
        """The simulated pace (N,) (mean over seeds and segments), and the std over seeds
        of the log of each seed's simulated pace (N,)."""
        with empty_slices_quiet():
            per_seed = np.nanmean(_segment_paces(with_noise_scale(model, s), plan, seeds),
                                  axis=1)
        with empty_slices_quiet(), np.errstate(divide='ignore', invalid='ignore'):
            return (np.nanmean(per_seed, axis=0),
                    np.nanstd(np.log(per_seed), axis=0, ddof=1) if seeds > 1
                    else np.zeros(n))

    with empty_slices_quiet():
        data = np.nanmean(np.concatenate([_data_paces(p, starts, length, model.dt)
                                          for p, starts, length in plan]), axis=0)
    sim, spread = paces(scale)
    first = sim.copy()
    lo, hi = SCALE_RANGE
    ok = np.isfinite(data) & (data > 0) & np.isfinite(sim) & (sim > 0)
    for i in np.flatnonzero(~ok):
        reason[i] = 'no pace in the training data' if not (np.isfinite(data[i])
                                                            and data[i] > 0) else \
            'the free run does not move'
    # (C3) only a significant miss is corrected: the data are one realisation, so their pace
    # differs from the runs' mean by about the runs' own spread
    with np.errstate(divide='ignore', invalid='ignore'):
        miss = np.abs(np.log(data / sim))
    tolerance = np.maximum(SIGNIFICANCE * np.nan_to_num(spread) * math.sqrt(1.0 + 1.0 / seeds),
                           MIN_MISS)
    within = ok & (miss <= tolerance)
    for i in np.flatnonzero(within):
        reason[i] = 'pace within its free runs\' own spread'
    active = ok & ~within
    start_scale = scale.copy()
    done = 0
    gamma = np.ones(n)
    for _ in range(int(iterations)):
        if not active.any():
            break
        step = np.ones(n)
        step[active] = (data[active] / sim[active]) ** (1.0 / gamma[active])
        new = np.where(active, np.clip(scale * step, lo, hi), scale)
        if np.allclose(new, scale, rtol=0.01, atol=0.0):
            break
        previous, prev_sim = scale, sim
        scale = new
        sim, _ = paces(scale)
        done += 1
        # the secant slope of log pace against log s (C2): how strongly this animal's pace
        # answers its noise (1 without a pull; less where a pull bounds its range)
        moved = active & (np.abs(np.log(scale / previous)) > 1e-3)
        with np.errstate(divide='ignore', invalid='ignore'):
            slope = np.log(sim / prev_sim) / np.log(scale / previous)
        # a pace that hardly answers the noise is the drift's: the noise cannot set it
        deaf = moved & ~(slope >= MIN_ELASTICITY)
        for i in np.flatnonzero(deaf):
            reason[i] = 'its pace is its drift\'s, not its noise\'s'
        scale = np.where(deaf, start_scale, scale)
        active &= ~deaf & np.isfinite(sim) & (sim > 0)
        gamma = np.where(moved & ~deaf, np.clip(slope, MIN_ELASTICITY, 1.5), gamma)
        if deaf.any():
            sim, _ = paces(scale)
    for i in np.flatnonzero(active & (scale <= lo) & (sim > 1.1 * data)):
        reason[i] = 'its drift alone outpaces it'
    return {'scale': scale, 'data_pace': data, 'sim_pace': sim, 'uncalibrated_pace': first,
            'iterations': done, 'segments': sum(len(s) for _, s, _ in plan),
            'reason': reason}


def describe_calibration(result: dict, agents) -> str:
    """One line for ``herd-ros fit``: the factors' range and the herd's pace before/after."""
    s = np.asarray(result['scale'], dtype=float)
    with empty_slices_quiet():
        d, a, b = (float(np.nanmean(result[k])) for k in ('data_pace', 'uncalibrated_pace',
                                                          'sim_pace'))
    text = (f'noise scale: {np.nanmin(s):.2f}-{np.nanmax(s):.2f} (median {np.median(s):.2f}) '
            f'on each animal\'s noise std, so the free run keeps its '
            f'{PACE_WINDOW_S / 60:g}-minute pace on the training data: herd pace '
            f'{_fmt(a)} -> {_fmt(b)} m/s vs {_fmt(d)} ({result["iterations"]} iterations, '
            f'{result["segments"]} segments)')
    why = {}
    for agent, r in zip(agents, result['reason']):
        if r:
            why.setdefault(r, []).append(agent)
    for r, names in why.items():
        text += f'; {r}: ' + ', '.join(names)
    return text


def _fmt(x: float) -> str:
    return f'{x:.3g}' if math.isfinite(x) else 'n/a'
