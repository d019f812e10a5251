"""`herd-ros flock`: run the report's flocking experiments (Olfati-Saber / La & Sheng).

Writes to ``--out``:

* ``metrics.csv``: ``seed,t,deviation_energy,velocity_mismatch,cohesion_radius,connectivity,
  tracking_mse,collisions`` every step, then the same six over the non-adversarial agents
  (suffix ``_non_adversarial``);
* ``trajectories.csv``: ``seed,time,agent,x,y`` every ``--record-every`` seconds;
* ``target.csv``: ``seed,time,x,y``;
* ``snapshots.png`` (t = 0, 0.5, 2 s, the target's closest pass of an obstacle and the end,
  first seed: agents, r-disc links, target,
  obstacles and β-agents), ``metrics.png`` (metric curves, median and range over seeds),
  ``tracking_error.png`` (‖q̄ − q_r‖ per seed); ``animation.gif`` with ``--gif``.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from herd_ros.errors import HerdInputError

HELP = ('flocking experiments of the report (Olfati-Saber α/β/γ with centre-of-mass feedback): '
        'metrics, trajectories, figures')

SNAPSHOT_TIMES = (0.0, 0.5, 2.0)


def add_arguments(parser):
    from herd_ros.flocking.olfati_saber import GAMMA_MODES
    from herd_ros.flocking.scenarios import DEFAULT_ADVERSARIES, DEFAULT_SUBSTEPS, DT, SCENARIOS

    parser.add_argument('--scenario', required=True, choices=SCENARIOS,
                        help='experiment (see herd_ros/flocking/scenarios.py)')
    parser.add_argument('--agents', type=int, default=50, help='number of agents N')
    parser.add_argument('--seeds', type=int, default=1,
                        help='number of random placements (seeds 0..N-1)')
    parser.add_argument('--first-seed', type=int, default=0, help='first seed')
    parser.add_argument('--gamma', choices=GAMMA_MODES, default=None,
                        help='γ feedback: plain target, global or local centre of mass '
                             '(default: flocking.gamma_mode of --params, else local-com)')
    parser.add_argument('--duration', type=float, default=None,
                        help='seconds (default: the scenario\'s, 20 s; turning: one lap)')
    parser.add_argument('--adversaries', type=int, default=DEFAULT_ADVERSARIES,
                        help='adversarial agents in the adversarial-* scenarios')
    parser.add_argument('--dt', type=float, default=DT, help='metric/recording step (s)')
    parser.add_argument('--substeps', type=int, default=DEFAULT_SUBSTEPS,
                        help='control/integration steps per dt (2: 100 Hz control)')
    parser.add_argument('--params', type=Path, default=None,
                        help='a ROS parameters YAML with controller.ros__parameters.flocking '
                             '(config/flocking.yaml); scenarios keep their own obstacles')
    parser.add_argument('--record-every', type=float, default=0.1,
                        help='seconds between rows of trajectories.csv / frames of the GIF')
    parser.add_argument('--gif', action='store_true', help='also write animation.gif')
    parser.add_argument('--out', type=Path, required=True, help='output directory')


def load_flocking_params(path: Path | None):
    """FlockingParams from a parameters YAML (``<node>: ros__parameters: flocking: ...``)."""
    from herd_ros.flocking.olfati_saber import FlockingParams

    if path is None:
        return FlockingParams()
    import yaml
    try:
        doc = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise HerdInputError(f'{path}: cannot read the parameters file ({exc})') from None
    for node in ('controller', '/**'):
        block = ((doc or {}).get(node) or {}).get('ros__parameters', {}) if isinstance(doc, dict) \
            else {}
        if isinstance(block, dict) and 'flocking' in block:
            return FlockingParams.from_mapping(block['flocking'], where=f'{path}: flocking')
    raise HerdInputError(f'{path}: no controller.ros__parameters.flocking block')


def run(args) -> int:
    from tqdm import tqdm

    from herd_ros.flocking.scenarios import make_scenario, simulate, tracking_summary

    if args.seeds < 1:
        raise HerdInputError(f'--seeds must be at least 1 (got {args.seeds})')
    if args.duration is not None and not args.duration > 0:
        raise HerdInputError(f'--duration must be > 0 (got {args.duration})')
    if not args.record_every > 0:
        raise HerdInputError(f'--record-every must be > 0 (got {args.record_every})')
    params = load_flocking_params(args.params)
    if args.gamma:
        params = params.with_(gamma_mode=args.gamma)
    scenario = make_scenario(args.scenario, n_adversaries=args.adversaries)
    duration = scenario.duration if args.duration is None else args.duration
    record_every = max(1, int(round(args.record_every / args.dt)))
    n_steps = int(round(duration / args.dt))
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))

    runs = []
    with tqdm(total=n_steps * len(seeds), desc=f'flock {args.scenario}', unit='step',
              leave=False) as bar:
        for seed in seeds:
            runs.append(simulate(scenario, params, n_agents=args.agents, seed=seed,
                                 duration=duration, dt=args.dt, substeps=args.substeps,
                                 record_every=record_every, progress=bar.update))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written = write_csvs(out, runs)
    written += plot_all(out, runs)
    if args.gif:
        written.append(write_gif(out / 'animation.gif', runs[0], args.record_every))
    print_summary(args, params, runs, [tracking_summary(r) for r in runs], written)
    return 0


# --- files -------------------------------------------------------------------------------

def write_csvs(out: Path, runs) -> list[Path]:
    import pandas as pd

    from herd_ros.flocking.metrics import METRIC_NAMES

    metric_frames, traj_frames, target_frames = [], [], []
    for r in runs:
        frame = {'seed': r.seed, 't': r.metric_times}
        frame.update({k: r.metrics[k] for k in METRIC_NAMES})
        frame.update({f'{k}_non_adversarial': r.metrics_non_adversarial[k] for k in METRIC_NAMES})
        metric_frames.append(pd.DataFrame(frame))
        T, N = r.positions.shape[:2]
        traj_frames.append(pd.DataFrame({
            'seed': r.seed, 'time': np.repeat(r.times, N), 'agent': np.tile(np.arange(N), T),
            'x': r.positions[:, :, 0].ravel(), 'y': r.positions[:, :, 1].ravel()}))
        target_frames.append(pd.DataFrame({'seed': r.seed, 'time': r.times,
                                           'x': r.target_positions[:, 0],
                                           'y': r.target_positions[:, 1]}))
    paths = [out / 'metrics.csv', out / 'trajectories.csv', out / 'target.csv']
    pd.concat(metric_frames).to_csv(paths[0], index=False, float_format='%.6g')
    pd.concat(traj_frames).to_csv(paths[1], index=False, float_format='%.4f')
    pd.concat(target_frames).to_csv(paths[2], index=False, float_format='%.4f')
    return paths


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


def print_summary(args, params, runs, summaries, written):
    def med(values):
        values = [v for v in values if not math.isnan(v)]
        return float(np.median(values)) if values else float('nan')

    adversarial = runs[0].adversaries.any()
    who = 'non-adversarial agents' if adversarial else 'all agents'
    conn = [r.metrics_non_adversarial['connectivity'] for r in runs]
    collisions = sum(int(r.metrics['collisions'].sum() > 0) for r in runs)
    unsettled = sum(math.isnan(s['settle_time']) for s in summaries)
    print(f'herd-ros flock: {args.scenario}, {args.agents} agents, γ {params.gamma_mode}, '
          f'{len(runs)} seed(s), {runs[0].metric_times[-1]:.1f} s at dt {args.dt} '
          f'({args.substeps} control steps per dt)')
    print(f'  final connectivity ({who}): median {med([c[-1] for c in conn]):.3f}, '
          f'min {min(c[-1] for c in conn):.3f}')
    print(f'  runs with an agent inside an obstacle: {collisions} of {len(runs)}')
    print(f'  CoM error ({who}): steady {med([s["steady_com_error"] for s in summaries]):.3f} m '
          f'(mean of last 5 s), '
          f'peak after 5 s {med([s["peak_com_error"] for s in summaries]):.3f} m, '
          f'settles below 1 m at {med([s["settle_time"] for s in summaries]):.2f} s '
          f'(median; {unsettled} run(s) never settle)')
    km = med([r.metrics_non_adversarial['velocity_mismatch'][-1] for r in runs])
    print(f'  final velocity mismatch ({who}): median {km:.3g} m²/s²')
    print('  wrote ' + ', '.join(str(p) for p in written))
