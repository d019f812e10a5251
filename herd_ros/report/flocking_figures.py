"""Figures of `herd-ros flock` runs (:mod:`herd_ros.flocking.scenarios`): snapshots of the
flock, the report's metrics over time, and an animation of one run."""
from __future__ import annotations

from pathlib import Path

import numpy as np

#: times (s) of the snapshot figure
SNAPSHOT_TIMES = (0.0, 0.5, 2.0)


def _frame_index(run, t: float) -> int:
    return int(np.argmin(np.abs(run.times - t)))


def draw_snapshot(ax, run, k: int):
    """Agents (adversaries in red), r-disc links, target, obstacles and β-agents at frame k."""
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Circle

    from herd_ros.flocking.olfati_saber import beta_agents, neighbour_pairs

    q, p, t = run.positions[k], run.velocities[k], run.times[k]
    params = run.params
    pairs = neighbour_pairs(q, params.range)
    ax.add_collection(LineCollection(q[pairs], colors='0.75', linewidths=0.6, zorder=1))
    obstacles = run.scenario.obstacles.at_time(t)
    for c, rad in zip(obstacles.centres, obstacles.radii):
        ax.add_patch(Circle(c, rad, color='0.35', alpha=0.5, zorder=0))
    if len(obstacles):
        q_hat, _ = beta_agents(q, p, obstacles)
        near = np.linalg.norm(q_hat - q[:, None, :], axis=2) < params.beta_range
        if near.any():
            ax.scatter(q_hat[near][:, 0], q_hat[near][:, 1], marker='x', s=14, color='tab:orange',
                       label='β-agents', zorder=3)
    honest = ~run.adversaries
    ax.quiver(q[honest, 0], q[honest, 1], p[honest, 0], p[honest, 1], color='tab:blue',
              angles='xy', scale_units='xy', scale=4.0, width=0.003, zorder=2)
    ax.scatter(q[honest, 0], q[honest, 1], s=10, color='tab:blue', label='agents', zorder=3)
    if run.adversaries.any():
        ax.scatter(q[~honest, 0], q[~honest, 1], s=14, color='tab:red', label='adversaries',
                   zorder=3)
    ax.plot(*run.target_positions[k], marker='*', markersize=14, color='gold',
            markeredgecolor='k', linestyle='none', label='target', zorder=4)
    ax.set_title(f't = {t:.1f} s')
    ax.set_aspect('equal')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')


def plot_all(out: Path, runs) -> list[Path]:
    """Every figure of the flocking runs ``runs`` into ``out``; returns the files written."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from herd_ros.flocking.metrics import METRIC_NAMES

    paths = []
    first = runs[0]
    times = [t for t in SNAPSHOT_TIMES if t <= first.times[-1]]
    if len(first.scenario.obstacles):  # also the moment the target is nearest an obstacle
        gap = [np.min(np.linalg.norm(first.scenario.obstacles.at_time(t).centres - q_r, axis=1))
               for t, q_r in zip(first.times, first.target_positions)]
        times.append(float(first.times[int(np.argmin(gap))]))
    times.append(float(first.times[-1]))
    fig, axes = plt.subplots(1, len(times), figsize=(4.2 * len(times), 4.4))
    for ax, t in zip(np.atleast_1d(axes), times):
        draw_snapshot(ax, first, _frame_index(first, t))
    np.atleast_1d(axes)[0].legend(loc='best', fontsize=7)
    fig.suptitle(f'{first.scenario.name}, γ {first.params.gamma_mode}, seed {first.seed}')
    fig.tight_layout()
    paths.append(out / 'snapshots.png')
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    labels = {'deviation_energy': 'deviation energy (m²)',
              'velocity_mismatch': 'velocity mismatch (m²/s²)',
              'cohesion_radius': 'cohesion radius (m)',
              'connectivity': 'relative connectivity', 'tracking_mse': 'CoM error² (m²)',
              'collisions': 'agents inside obstacles'}
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), sharex=True)
    t = first.metric_times
    adversarial = first.adversaries.any()
    for ax, name in zip(axes.ravel(), METRIC_NAMES):
        sets = [('all agents', 'tab:blue', 'metrics')]
        if adversarial:
            sets.append(('non-adversarial', 'tab:green', 'metrics_non_adversarial'))
        for label, color, attr in sets:
            values = np.array([getattr(r, attr)[name] for r in runs])
            ax.plot(t, np.median(values, axis=0), color=color, label=label)
            if len(runs) > 1:
                ax.fill_between(t, values.min(axis=0), values.max(axis=0), color=color, alpha=0.2)
        if name in ('velocity_mismatch', 'tracking_mse', 'deviation_energy'):
            ax.set_yscale('symlog', linthresh=1e-2)
        ax.set_ylabel(labels[name])
        ax.grid(True, alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel('t (s)')
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f'{first.scenario.name}, γ {first.params.gamma_mode}: median and range over '
                 f'{len(runs)} seed(s)')
    fig.tight_layout()
    paths.append(out / 'metrics.png')
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 4))
    for r in runs:
        ax.semilogy(r.metric_times, np.maximum(r.com_error(adversarial), 1e-4), lw=0.8,
                    label=f'seed {r.seed}' if len(runs) <= 10 else None)
    ax.axhline(1.0, color='k', ls='--', lw=0.8, label='1 m')
    ax.set_xlabel('t (s)')
    ax.set_ylabel('‖q̄ − q_r‖ (m)' + (' (non-adversarial)' if adversarial else ''))
    ax.set_title(f'CoM-to-target error, {first.scenario.name}, γ {first.params.gamma_mode}')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    paths.append(out / 'tracking_error.png')
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def write_gif(path: Path, run, frame_period: float) -> Path:
    """Animation of one run (matplotlib PillowWriter), one frame per recorded time."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    q = run.positions
    lo = np.minimum(q.min(axis=(0, 1)), run.target_positions.min(axis=0)) - 5
    hi = np.maximum(q.max(axis=(0, 1)), run.target_positions.max(axis=0)) + 5
    lo = np.maximum(lo, run.target_positions.min(axis=0) - 60)
    hi = np.minimum(hi, run.target_positions.max(axis=0) + 60)
    fig, ax = plt.subplots(figsize=(8, 8 * (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9) + 0.8))

    def update(k):
        ax.clear()
        draw_snapshot(ax, run, k)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])

    anim = FuncAnimation(fig, update, frames=len(run.times))
    anim.save(path, writer=PillowWriter(fps=max(1, int(round(1.0 / frame_period)))))
    plt.close(fig)
    return path
