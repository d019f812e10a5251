"""`herd-ros simulate`: run a model file forward with noise drawn from Q_i."""
from __future__ import annotations

import numpy as np

from herd_ros.cli.common import progress
from herd_ros.errors import HerdInputError

# the model, the simulator and the data readers are imported where they are used:
# `herd-ros simulate --help` then reads no more than argparse

HELP = ('simulate the learned laws of a model file (noise from each agent\'s Q_i, or its '
        'noise regimes when the file has them, times its noise_scale)')


def add_arguments(p):
    """The verb's options (``herd-ros VERB --help``)."""
    p.add_argument('model', help='model file written by `herd-ros fit`')
    p.add_argument('--steps', type=int, default=3600, help='number of time steps')
    p.add_argument('--seed', type=int, default=0, help='noise seed')
    p.add_argument('-o', '--output', required=True, help='trajectory CSV to write')
    p.add_argument('--initial', help='trajectory CSV whose first two steps (per agent: the '
                                     'first two where it is present) start the simulation '
                                     '(default: agents on a ring about the field)')
    p.add_argument('--no-noise', action='store_true', help='deterministic simulation (w = 0)')
    p.add_argument('--seen-like-initial', action='store_true',
                   help='with --initial on the model\'s clock: write each agent only where '
                        'the initial trajectory has it (silent, late and ended collars as in '
                        'the data), the way the free-run figures compare a run with data')


def default_initial_positions(model, seed=0):
    """Agents on a ring of radius ~ the median equilibrium distance about the field centres."""
    if hasattr(model, 'laws'):
        centres = np.concatenate([model.laws[a].basis.centers for a in model.agents])
        deq = np.concatenate([model.laws[a].equilibrium_distance() for a in model.agents])
    else:                                    # shared law: a quarter of its radius
        centres = np.concatenate([b.centers for b in model.bases])
        deq = np.array([model.profile.radius / 4.0])
    c = centres.mean(axis=0)
    deq = deq[np.isfinite(deq) & (deq > 0)]
    radius = float(np.clip(np.median(deq) if len(deq) else 10.0, 2.0, 100.0))
    n = model.n_agents
    ang = 2 * np.pi * np.arange(n) / n + np.random.default_rng(seed).uniform(0, 2 * np.pi)
    return c + radius * np.column_stack([np.cos(ang), np.sin(ang)]) * max(1.0, n / 6)


def first_state(p: np.ndarray, dt: float, source) -> tuple[np.ndarray, np.ndarray]:
    """p^0 and u^0 of every agent from the first two consecutive steps where it is present
    (collars start late: the first row of a real recording has agents missing)."""
    from herd_ros.simulation.herd_simulator import first_pairs
    k, found = first_pairs(p)
    if not found.all():
        raise HerdInputError(f'{source}: an agent is never present at two consecutive steps')
    idx = np.arange(p.shape[1])
    return p[k, idx], (p[k + 1, idx] - p[k, idx]) / dt


def aligned_data(run, positions, dt: float):
    """The positions from the run's first step at which an agent is present two steps in a
    row — where the simulation's first step stands (an agent that starts later is started
    from its own first positions and is absent from the data until then) — when the run is
    on the model's clock; else None."""
    from herd_ros.simulation.herd_simulator import first_pairs
    steps = np.diff(run.times)
    if not len(steps) or not np.allclose(steps, dt, rtol=1e-6, atol=1e-9):
        return None
    return positions[int(first_pairs(positions)[0].min()):]


def compare_with_data(seen, span, dt: float, source) -> str:
    """The free-run statistics of the simulation against the initial trajectory over the
    steps both cover: ``seen`` the simulation seen where the data ``span`` are
    (:func:`~herd_ros.simulation.free_run.observed_like`)."""
    from herd_ros.nan_stats import empty_slices_quiet
    from herd_ros.simulation.free_run import STATISTICS, shape_and_pace
    if len(span) < 4:
        return f'(too few steps of {source} to compare with)'
    with empty_slices_quiet():
        d, r = shape_and_pace(span, dt), shape_and_pace(seen, dt)
        cells = []
        for k in STATISTICS:
            a, b = float(np.nanmean(d[k])), float(np.nanmean(r[k]))
            rel = f'{100 * (b / a - 1):+.0f} %' if a > 0 and np.isfinite(b) else 'n/a'
            cells.append(f'{k.replace("_", " ")} {b:.3g} vs {a:.3g} ({rel})')
    return (f'against {source} over {len(span)} steps (herd means; the run seen where the '
            f'data are): ' + '; '.join(cells))


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.data_sources import load_runs
    from herd_ros.herd_dynamics import HerdDynamics
    from herd_ros.simulation.statistics import herd_statistics
    from herd_ros.trajectory import HerdTrajectory, write_trajectory_csv

    if args.steps < 2:
        raise HerdInputError(f'--steps must be at least 2, got {args.steps}')
    dyn = HerdDynamics.load(args.model)
    model = dyn.model
    u0 = None
    if args.seen_like_initial and not args.initial:
        raise HerdInputError('--seen-like-initial needs --initial')
    data = None
    if args.initial:
        runs, _ = load_runs(args.initial)
        r = runs[0]
        missing = [a for a in model.agents if a not in r.agents]
        if missing:
            raise HerdInputError(f'{args.initial}: no data for agent(s) {", ".join(missing)}')
        p = r.positions[:, [r.agents.index(a) for a in model.agents]]
        p0, u0 = first_state(p, model.dt, args.initial)
        data = aligned_data(r, p, model.dt)
        if args.seen_like_initial and data is None:
            raise HerdInputError(f'{args.initial}: --seen-like-initial needs a trajectory on '
                                 f'the model\'s clock ({model.dt:g} s)')
    else:
        p0 = default_initial_positions(model, args.seed)
    bar = progress(total=args.steps, desc='simulating', unit='step')
    traj = dyn.simulate(p0, args.steps, u0, seed=args.seed, noise=not args.no_noise,
                        progress=bar.update)
    bar.close()
    if data is not None:
        from herd_ros.simulation.free_run import observed_like
        seen, span = observed_like(traj, data, traj.times[0] + model.dt * np.arange(len(data)))
        print(compare_with_data(seen, span, model.dt, args.initial))
        if args.seen_like_initial:          # the steps past the data's: nowhere seen
            out = np.full(traj.positions.shape, np.nan)
            out[:len(seen)] = seen
            traj = HerdTrajectory(traj.times, list(traj.agents), out)
    write_trajectory_csv(args.output, traj)
    stats = herd_statistics(traj)
    print(f'wrote {args.steps} steps of {model.n_agents} agents to {args.output}'
          + (' (each agent where the initial trajectory has it)' if args.seen_like_initial
             else ''))
    print(f'{"agent":>12} {"mean dist":>10} {"std dist":>10} {"mean speed":>11} {"std speed":>10}')
    for a, s in stats.items():
        print(f'{a:>12} {s["mean_distance"]:10.2f} {s["std_distance"]:10.2f} '
              f'{s["mean_speed"]:11.3f} {s["std_speed"]:10.3f}')
    return 0
