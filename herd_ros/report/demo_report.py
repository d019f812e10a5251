"""Report of the live demo: what the robots learned from the cows, and how alike they move.

Plain numpy/matplotlib (no rclpy): the demo node records arrays, this turns them into

* ``fig_params.png`` — learned parameters over time (damping of every cow, and the pair
  equilibrium distances θ2/θ1 where positive);
* ``fig_trajectories.png`` — robots vs cows over the paddock fence;
* ``fig_statistics.png`` — herd statistics bars, robots vs cows (Schwager et al. Fig. 6);
* ``summary.json`` — ``cows`` and ``robots``: {name: {mean_distance, std_distance,
  mean_speed, std_speed}}, plus ``relative_difference`` per assigned pair and run facts.

The robots run all the time; the animals' herd poses miss an animal whose collar is silent
(stale) or not yet, or no longer, reporting, and a statistic over "the others" changes with
who is present. So the robots are seen like their animals (:func:`seen_like_animals`: a
robot's sample where its animal has no herd pose is left out), the observation applied to
both sides as in :func:`herd_ros.simulation.free_run.observed_like`; ``robots_all_samples``
keeps the robots' statistics over every sample.
"""
from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from herd_ros.report.fit_figures import statistics_figure  # noqa: E402
from herd_ros.simulation.statistics import STATISTICS, herd_statistics  # noqa: E402
from herd_ros.trajectory import HerdTrajectory  # noqa: E402


def params_figure(times, thetas, agents, path: Path, law: str = 'pairwise',
                  profile_size: int = 0):
    """Damping per agent and, for the pairwise law, θ2/θ1 per pair (equilibrium distances);
    for the shared law, the herd mean of each distance-profile coefficient; over data time."""
    t = np.asarray(times, dtype=float)
    th = np.asarray(thetas, dtype=float)  # (T, N, P)
    n = len(agents)
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    rel = (t - t[0]) / 60.0
    for i, a in enumerate(agents):
        axes[0].plot(rel, th[:, i, 0], label=a if n <= 8 else None, lw=0.8)
    if law == 'shared':
        for b in range(profile_size):
            axes[1].plot(rel, th[:, :, 1 + b].mean(axis=1), lw=0.9, label=f'c_{b + 1}')
        axes[1].set_title('shared law: herd mean of the distance-profile coefficients')
        axes[1].legend(fontsize=7)
    else:
        for i in range(n):
            for k in range(n - 1):
                t1, t2 = th[:, i, 1 + k], th[:, i, n + k]
                with np.errstate(divide='ignore', invalid='ignore'):
                    deq = np.where(t1 > 0, t2 / t1, np.nan)
                axes[1].plot(rel, deq, lw=0.8)
        axes[1].set_title('learned equilibrium distances θ2/θ1 (m), every pair')
        axes[1].set_ylim(0, 100)
    axes[0].set_title('learned damping a_i')
    axes[0].set_xlabel('bag time (min)')
    if n <= 8:
        axes[0].legend(fontsize=7)
    axes[1].set_xlabel('bag time (min)')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def trajectories_over_fence(cows: HerdTrajectory, robots: HerdTrajectory, fence, path: Path):
    """Cows and robots in the map frame with the fence polygon."""
    fig, ax = plt.subplots(figsize=(7.5, 6))
    if fence is not None and len(fence) >= 3:
        f = np.vstack([fence, fence[:1]])
        ax.plot(f[:, 0], f[:, 1], 'k-', lw=1.2, label='fence')
    for i, a in enumerate(cows.agents):
        ax.plot(cows.positions[:, i, 0], cows.positions[:, i, 1], '-', color=f'C{i}', lw=0.8,
                label=f'{a} (animal)' if len(cows.agents) <= 6 else None)
    for i, r in enumerate(robots.agents):
        ax.plot(robots.positions[:, i, 0], robots.positions[:, i, 1], '--', color=f'C{i}',
                lw=0.8, label=f'{r} (robot)' if len(robots.agents) <= 6 else None)
    ax.set_aspect('equal')
    ax.set_xlabel('x east (m)')
    ax.set_ylabel('y north (m)')
    ax.legend(fontsize=7, loc='best')
    ax.set_title('animals (solid) and the robots that learned from them (dashed)')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _finite_rows(traj: HerdTrajectory) -> HerdTrajectory:
    """The ticks where at least one agent has a position (missing agents stay NaN)."""
    keep = np.isfinite(traj.positions).all(axis=2).any(axis=1)
    return HerdTrajectory(traj.times[keep], list(traj.agents), traj.positions[keep])


def seen_like_animals(cows: HerdTrajectory, robots: HerdTrajectory,
                      assignment) -> HerdTrajectory:
    """``robots`` with each robot's sample NaN where its animal (``assignment``, in robot
    order) has no herd pose: the last herd snapshot at or before the sample (within one
    herd-clock step) lacks it, or there is none."""
    p = np.array(robots.positions, dtype=float)
    if cows.n_steps == 0 or robots.n_steps == 0:
        return robots
    steps = np.diff(cows.times)
    step = float(np.median(steps)) if len(steps) else np.inf
    k = np.searchsorted(cows.times, robots.times, side='right') - 1
    late = (k < 0) | (robots.times - cows.times[np.maximum(k, 0)] > step * (1 + 1e-9))
    for j, a in enumerate(assignment):
        if a not in cows.agents:
            continue
        present = np.isfinite(cows.positions[:, cows.agents.index(a)]).all(-1)
        p[late | ~present[np.maximum(k, 0)], j] = np.nan
    return HerdTrajectory(robots.times, list(robots.agents), p)


def seen_at_fixes(times, fix_times, fix_positions) -> np.ndarray:
    """Each robot as its animal's track sees the animal: at herd tick t, the robot's position
    at its animal's last accepted fix at or before t (NaN before the first).

    A duty-cycled track is informed only when a fix comes in: on the herd clock it stands
    still between fixes (a random walk's prediction) and jumps at each, so its speed and the
    spread of its speed at the clock are the collar's sampling as much as the animal's
    motion. A robot seen the same way is compared like with like; at 1 Hz fixes this is the
    robot itself.

    Args:
        times: (T,) herd ticks.
        fix_times: per robot, its animal's accepted fix stamps (F_k,), increasing.
        fix_positions: per robot, its own positions (F_k, 2) at those stamps.

    Returns:
        (T, R, 2) positions.
    """
    times = np.asarray(times, dtype=float)
    out = np.full((len(times), len(fix_times), 2), np.nan)
    for k, (ft, fp) in enumerate(zip(fix_times, fix_positions)):
        ft = np.asarray(ft, dtype=float)
        if not len(ft):
            continue
        j = np.searchsorted(ft, times + 1e-9, side='right') - 1
        ok = j >= 0
        out[ok, k] = np.asarray(fp, dtype=float).reshape(-1, 2)[j[ok]]
    return out


#: a robot passes when each of its statistics is within this of its animal's (issue 30)
PASS_BAR = 0.30


def verdict(cows: HerdTrajectory, robots: HerdTrajectory, assignment, rel: dict,
            herd_rel: dict) -> dict:
    """Each robot against its animal: where it started (its first position, against the
    animal's latest herd pose at that moment, or its first one if it had none yet; m) and
    whether every statistic is within :data:`PASS_BAR`; the herd's likewise."""
    out = {'bar': PASS_BAR, 'robots': {}}
    for k, (r, a) in enumerate(zip(robots.agents, assignment)):
        start = float('nan')
        if a in cows.agents:
            pc = cows.positions[:, cows.agents.index(a)]
            pr = robots.positions[:, k]
            fc, fr = np.isfinite(pc).all(-1), np.isfinite(pr).all(-1)
            if fc.any() and fr.any():
                t0 = robots.times[np.argmax(fr)]
                before = np.flatnonzero(fc & (cows.times <= t0 + 1e-9))
                j = before[-1] if len(before) else np.argmax(fc)
                start = float(np.hypot(*(pr[np.argmax(fr)] - pc[j])))
        out['robots'][r] = {'animal': a, 'start_offset_m': start,
                            'pass': bool(r in rel and all(v <= PASS_BAR
                                                          for v in rel[r].values()))}
    out['herd_pass'] = bool(herd_rel) and all(v <= PASS_BAR for v in herd_rel.values())
    return out


def write_demo_report(out_dir, cows: HerdTrajectory, robots: HerdTrajectory,
                      assignment: list[str], param_times, param_thetas, fence=None,
                      facts: dict | None = None, law: str = 'pairwise',
                      profile_size: int = 0,
                      robots_at_fixes: HerdTrajectory | None = None,
                      cows_at_fixes: HerdTrajectory | None = None) -> dict:
    """Figures and ``summary.json`` of the live demo; returns the summary.

    The robots' statistics (``robots``, the verdict) see each robot like its animal: only
    where the animal has a herd pose (:func:`seen_like_animals`) and, given
    ``robots_at_fixes`` (the robots on the same ticks, :func:`seen_at_fixes`), where its
    animal's track was informed; ``robots_continuous`` keeps the robots' own positions at
    the ticks (where the animal has a pose), ``robots_all_samples`` every sample. Given
    ``cows_at_fixes`` (each animal's track at its last accepted fix, on the same ticks),
    the animals' statistics (``cows``) are taken the same way: between fixes a track is
    the tracker's prediction (a fitted collar's velocity carries it on), not the animal;
    ``cows_continuous`` keeps the herd poses'."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cows, robots = _finite_rows(cows), _finite_rows(robots)
    cow_stats = herd_statistics(cows) if cows.n_steps >= 2 else {}
    continuous_cows = cow_stats
    if cows_at_fixes is not None and robots_at_fixes is not None:
        seen_cows = _finite_rows(cows_at_fixes)
        cow_stats = herd_statistics(seen_cows) if seen_cows.n_steps >= 2 else {}
    every_sample = herd_statistics(robots) if robots.n_steps >= 2 else {}
    seen = _finite_rows(seen_like_animals(cows, robots, assignment))
    continuous = herd_statistics(seen) if seen.n_steps >= 2 else {}
    robot_stats = continuous
    if robots_at_fixes is not None:
        at_fixes = _finite_rows(seen_like_animals(cows, _finite_rows(robots_at_fixes),
                                                  assignment))
        robot_stats = herd_statistics(at_fixes) if at_fixes.n_steps >= 2 else {}
    rel = {}
    for r, a in zip(robots.agents, assignment):
        if r in robot_stats and a in cow_stats:
            rel[r] = {k: abs(robot_stats[r][k] - cow_stats[a][k]) / max(abs(cow_stats[a][k]),
                                                                         1e-12)
                      for k in STATISTICS}
    herd_rel = {}
    if cow_stats and robot_stats:
        for k in STATISTICS:
            c = np.mean([cow_stats[a][k] for a in cow_stats])
            r = np.mean([robot_stats[a][k] for a in robot_stats])
            herd_rel[k] = float(abs(r - c) / max(abs(c), 1e-12))
    figures = []
    if len(param_times) >= 2:
        params_figure(param_times, param_thetas, cows.agents, out / 'fig_params.png', law,
                      profile_size)
        figures.append('fig_params.png')
    if cows.n_steps >= 2 and robots.n_steps >= 2:
        trajectories_over_fence(cows, robots, fence, out / 'fig_trajectories.png')
        figures.append('fig_trajectories.png')
    if cow_stats and robot_stats:
        by_cow = {a: robot_stats[r] for r, a in zip(robots.agents, assignment) if r in robot_stats}
        statistics_figure(cow_stats, by_cow, out / 'fig_statistics.png', labels=('cows',
                                                                                  'robots'))
        figures.append('fig_statistics.png')
    summary = {'cows': cow_stats, 'cows_continuous': continuous_cows, 'robots': robot_stats,
               'robots_continuous': continuous,
               'robots_all_samples': every_sample,
               'assignment': dict(zip(robots.agents, assignment)),
               'relative_difference': rel, 'herd_relative_difference': herd_rel,
               'verdict': verdict(cows, robots, assignment, rel, herd_rel),
               'figures': figures, **(facts or {})}
    (out / 'summary.json').write_text(json.dumps(summary, indent=1))
    return summary
