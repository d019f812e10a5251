"""`herd-ros imitate-sim policy.yaml -o traj.csv`: simulate a swarm from a policy file.

Random starts in a region, single-integrator agents v = σ_vmax(Σ k θ)
(:mod:`herd_ros.imitation.boids`); writes a trajectory CSV with a ``run`` column.
"""
from __future__ import annotations

HELP = 'simulate a swarm from an imitation policy file into a trajectory CSV'


def add_arguments(parser):
    """The verb's options (``herd-ros VERB --help``)."""
    parser.add_argument('policy', help='policy YAML (kind: imitation)')
    parser.add_argument('-o', '--output', required=True, help='trajectory CSV to write')
    parser.add_argument('--agents', type=int, default=40, help='agents per run')
    parser.add_argument('--runs', type=int, default=20, help='independent runs')
    parser.add_argument('--duration', type=float, default=5.0, help='seconds per run')
    parser.add_argument('--seed', type=int, default=0, help='random seed')
    parser.add_argument('--noise', type=float, default=0.0,
                        help='std (m) of Gaussian noise on the recorded positions')
    parser.add_argument('--region', default='0,10,0,10',
                        help='start region XMIN,XMAX,YMIN,YMAX (m)')


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.cli.imitate import parse_walls
    from herd_ros.errors import HerdInputError
    from herd_ros.imitation.boids import simulate_runs
    from herd_ros.imitation.policy_file import read_policy_file
    from herd_ros.trajectory import write_trajectory_csv

    policy = read_policy_file(args.policy)
    for name in ('agents', 'runs'):
        if getattr(args, name) < 1:
            raise HerdInputError(f'--{name} must be at least 1')
    if args.agents < 2:
        raise HerdInputError('--agents must be at least 2 (a swarm)')
    if args.duration <= 0 or args.noise < 0:
        raise HerdInputError('--duration must be positive and --noise non-negative')
    region = parse_walls(args.region)
    runs = simulate_runs(policy, n_agents=args.agents, n_runs=args.runs,
                         duration=args.duration, region=region, noise_std=args.noise,
                         rng=args.seed)
    write_trajectory_csv(args.output, runs)
    print(f'wrote {args.output}: {args.runs} runs x {args.agents} agents x '
          f'{runs[0].n_steps} steps (dt {policy.dt:g} s, noise {args.noise:g} m)')
    return 0
