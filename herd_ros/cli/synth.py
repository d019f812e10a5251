"""`herd-ros synth`: data with known truth (the model class) or a realistic cow herd."""
from __future__ import annotations

from herd_ros.cli.common import parse_floats, parse_grid, progress
from herd_ros.errors import HerdInputError

# the model, the simulator and the writers are imported where they are used: `herd-ros
# synth --help` then reads no more than argparse

HELP = 'synthesize herd data: from a herd-model law (known truth) or the realistic cow scenario'


def add_arguments(p):
    """The verb's options (``herd-ros VERB --help``)."""
    p.add_argument('--law', choices=('schwager',), help='data from the herd model')
    p.add_argument('--scenario', choices=('cows',), help='realistic cows (not in the model '
                                                         'class): grazing/walking/resting')
    p.add_argument('-o', '--output', required=True, help='trajectory CSV to write')
    p.add_argument('--model', help='with --law: the model file to simulate (the truth); '
                                   'without it a random truth is drawn')
    p.add_argument('--truth-out', help='with --law and no --model: write the drawn truth here')
    p.add_argument('--agents', type=int, default=3, help='herd size')
    p.add_argument('--steps', type=int, default=20000, help='time steps (--law)')
    p.add_argument('--dt', type=float, default=1.0, help='clock step (s)')
    p.add_argument('--grid', default='6x6', help='truth RBF grid NXxNY (--law, no --model)')
    p.add_argument('--bounds', default='-75,75,-75,75',
                   help='truth grid bounds XMIN,XMAX,YMIN,YMAX (--law, no --model)')
    p.add_argument('--noise-std', type=float, default=0.05,
                   help='process noise std (m/s per step) of a drawn truth')
    p.add_argument('--duration', type=float, default=3600.0, help='seconds (--scenario cows)')
    p.add_argument('--gps-out', help='with --scenario cows: also write collar fixes (GPS CSV) '
                                     'with the collar error model')
    p.add_argument('--bag-out', help='with --scenario cows: also write the collar fixes as a '
                                     'rosbag2 (mcap) of NavSatFix on /herd/<cow>/fix')
    p.add_argument('--start-time', default='0',
                   help='with --scenario cows: epoch seconds or ISO-8601 UTC of the first '
                        'sample (sets the time of day the cows live in)')
    p.add_argument('--seed', type=int, default=0, help='random seed')


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    if (args.law is None) == (args.scenario is None):
        raise HerdInputError('give exactly one of --law schwager or --scenario cows')
    if args.law:
        return _law(args)
    return _cows(args)


def _law(args) -> int:
    from herd_ros.model import kinds
    from herd_ros.model.herd_model import HerdModel
    from herd_ros.simulation.herd_simulator import simulate
    from herd_ros.synthesis.known_truth import initial_positions, make_truth_model
    from herd_ros.trajectory import write_trajectory_csv
    if args.model:
        truth = kinds.load(args.model)
        if not isinstance(truth, HerdModel):
            raise HerdInputError(f'{args.model}: synth --law schwager simulates the pairwise '
                                 f'law (kind schwager2007)')
    else:
        truth = make_truth_model(args.agents, seed=args.seed, grid=parse_grid(args.grid),
                                 bounds=parse_floats(args.bounds, 4, '--bounds'), dt=args.dt,
                                 noise_std=args.noise_std)
        if args.truth_out:
            kinds.save(truth, args.truth_out)
            print(f'truth model: {args.truth_out}')
    p0 = initial_positions(truth, seed=args.seed,
                           spread=min(30.0, 5.0 * truth.n_agents))
    bar = progress(total=args.steps, desc='simulating', unit='step')
    traj = simulate(truth, args.steps, p0, seed=args.seed + 1, progress=bar.update)
    bar.close()
    write_trajectory_csv(args.output, traj)
    print(f'wrote {args.steps} steps of {truth.n_agents} agents (dt {truth.dt:g} s) '
          f'to {args.output}')
    return 0


def _cows(args) -> int:
    from herd_ros.synthesis.cow_scenario import simulate_cow_herd
    from herd_ros.trajectory import write_trajectory_csv
    traj = simulate_cow_herd(n_cows=args.agents, duration_s=args.duration, dt=args.dt,
                             seed=args.seed, start_time=_epoch(args.start_time))
    write_trajectory_csv(args.output, traj)
    print(f'wrote {traj.n_steps} steps of {traj.n_agents} cows (dt {args.dt:g} s) to '
          f'{args.output}')
    if args.gps_out or args.bag_out:
        from herd_ros.synthesis.collar_errors import simulate_collar_fixes, write_gps_csv
        fixes = simulate_collar_fixes(traj, seed=args.seed + 1)
        if args.gps_out:
            write_gps_csv(fixes, args.gps_out)
            print(f'collar fixes (synthetic GPS errors): {args.gps_out}')
        if args.bag_out:
            from herd_ros.io.bags import write_fix_bag
            write_fix_bag(args.bag_out, fixes)
            print(f'collar fixes as a rosbag2: {args.bag_out} ({len(fixes)} NavSatFix)')
    return 0


def _epoch(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        pass
    import pandas as pd
    try:
        return pd.Timestamp(text, tz='UTC').timestamp() if pd.Timestamp(text).tzinfo is None \
            else pd.Timestamp(text).timestamp()
    except ValueError:
        raise HerdInputError(f'--start-time takes epoch seconds or ISO-8601, got {text!r}') \
            from None
