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


def add_arguments(parser):
    """The verb's options (``herd-ros VERB --help``)."""
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
    parser.add_argument('-o', '--out', type=Path, required=True, help='output directory')


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
    """Run the verb on the parsed ``args``; returns the exit status."""
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
    from herd_ros.report.flocking_figures import plot_all, write_gif
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
    """The flocking runs as trajectory CSVs in ``out``; returns the files written."""
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


def print_summary(args, params, runs, summaries, written):
    """The flocking verb's short summary on stdout."""
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
