"""`herd-ros demo`: the main job on a recorded herd (by default the shipped real one).

Live (default): the ROS graph replay → gps_ingest → estimator → controller → fleet_sim in one
process (:mod:`herd_ros.cli.live_demo`); robots learn from the animals while they move and
move like them. Everything herd-specific (datum, clock, field, fence, robots, replay rate)
comes from the bag (:mod:`herd_ros.herd_setup`) and is printed. Report: parameters over time,
robots vs animals over the fence, statistics bars, ``summary.json``, ``herd_poses.csv``,
``herd_predictions.csv``.

``--offline``: bag → ingest → batch fit → validation against constant-velocity and stay-put
baselines → simulation of the learned laws → the paper's figures.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from herd_ros.errors import HerdInputError

HELP = 'run the main job on a recorded herd (live ROS graph, or --offline fit)'

#: The default recording: 19 wild baboons, one hour of 1 Hz GPS (real animals: see
#: bags/README.md for why this one).
BAG_NAME = 'baboons_1h'


def shipped_bag(name: str = BAG_NAME) -> Path:
    """A shipped bag: ./bags/ of a source checkout, else the installed share directory."""
    local = Path(__file__).resolve().parents[2] / 'bags' / name
    for candidate in (Path.cwd() / 'bags' / name, local):
        if candidate.exists():
            return candidate
    try:
        from ament_index_python.packages import get_package_share_directory
        share = Path(get_package_share_directory('herd_ros')) / 'bags' / name
        if share.exists():
            return share
    except Exception:  # noqa: BLE001 — no ament index: fall through to the error
        pass
    raise HerdInputError(f'the shipped bag {name} was found neither in ./bags nor in the '
                         f'herd_ros share directory; pass --bag')


def add_arguments(p):
    """The verb's options (``herd-ros VERB --help``)."""
    p.add_argument('-o', '--out', default='demo_out', help='report directory')
    p.add_argument('--bag', help=f'bag to use (default: the herd file\'s bag, else the shipped '
                                 f'bags/{BAG_NAME}, 19 wild baboons)')
    p.add_argument('--herd', metavar='HERD_YAML',
                   help='herd file (herd-ros herd-file writes one; the launch file reads the '
                        'same); default: everything derived from the bag')
    p.add_argument('--dt', type=float, default=None,
                   help='the model\'s step (s); default: the median fix interval (at least '
                        '5 s live); /herd/poses ticks at a divisor of it, fine enough to '
                        'carry each fix within a step')
    p.add_argument('--grid', default='auto',
                   help='RBF grid of the environment field (--offline; auto = chosen by '
                        'cross-validation)')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--rate', type=float, default=None,
                   help='bag replay speed-up; default: the bag plays in about four minutes')
    p.add_argument('--herding', action='store_true',
                   help='instead: the herding graph live (herd_sim -> controller mode herding '
                        '-> fleet_sim, as launch/herding.launch.py): robots drive simulated '
                        'sheep into a goal circle; --rate defaults to 20 (simulated seconds '
                        'per second)')
    p.add_argument('--animals', type=int, default=14,
                   help='--herding: number of animals (default 14)')
    p.add_argument('--herders', type=int, default=1,
                   help='--herding: number of robots herding (default 1)')
    p.add_argument('--herder', choices=('strombom', 'model'), default='strombom',
                   help="--herding: the robots' policy: strombom (Strömbom et al. 2014's "
                        "shepherd) or model (the learned response, refitted online; "
                        "learned at start, Strömbom's meanwhile) (default: strombom)")
    p.add_argument('--model-warmup', choices=('strombom', 'hold'), default='strombom',
                   help="--herding --herder model: what the robots do while the model herder "
                        "learns: strombom (Strömbom's shepherd herds meanwhile) or hold (they "
                        "hold still; the model herder does all the herding) "
                        "(default: strombom)")
    p.add_argument('--offline', action='store_true',
                   help='offline pipeline instead: ingest, batch fit, validation, simulation')


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    if args.herding:
        return run_herding(args)
    if args.offline:
        return run_offline(args)
    from herd_ros.cli.live_demo import run_live_demo
    if args.rate is not None and not args.rate > 0:
        raise HerdInputError(f'--rate must be positive, got {args.rate}')
    if args.dt is not None and not args.dt > 0:
        raise HerdInputError(f'--dt must be positive, got {args.dt}')
    herd_bag = None
    if args.herd:
        from herd_ros.herd_file import read_herd_file
        if args.dt is not None:
            raise HerdInputError('--dt and --herd: the herd file fixes dt (edit it there)')
        _, herd_bag = read_herd_file(args.herd)
    bag = Path(args.bag) if args.bag else herd_bag or shipped_bag()
    if not bag.exists():
        raise HerdInputError(f'{bag}: no such bag')
    t0 = time.perf_counter()
    summary = run_live_demo(bag, args.out, rate=args.rate, dt=args.dt, herd_file=args.herd)
    print(f'\ndemo done in {time.perf_counter() - t0:.0f} s: {summary["herd_snapshots"]} herd '
          f'snapshots, {summary["model_updates"]} model updates, {summary["robot_samples"]} '
          f'robot samples. Herd statistics, animals vs robots (mean over the herd; each '
          f'animal and its robot seen at the animal\'s fixes, where its track was informed, '
          f'and where it has a herd pose, from the moment the robot\'s law took over; in '
          f'brackets the herd poses and the robots\' own positions at the ticks):')
    cows, robots = summary['cows'], summary['robots']
    cows_own = summary.get('cows_continuous') or {}
    own = summary.get('robots_continuous') or {}
    for key in ('mean_distance', 'std_distance', 'mean_speed', 'std_speed'):
        c, r, c_own, r_own = (sum(v[key] for v in s.values()) / max(len(s), 1)
                              for s in (cows, robots, cows_own, own))
        unit = 'm' if 'distance' in key else 'm/s'
        print(f'  {key:14s} animals {c:8.3f} {unit:3s}  robots {r:8.3f} {unit:3s}  '
              f'({100 * summary["herd_relative_difference"].get(key, float("nan")):.0f} % apart)'
              f'  [{c_own:8.3f} vs {r_own:8.3f}]')
    v = summary['verdict']
    since = summary.get('law_since') or {}
    t_first = summary.get('bag_start_s')

    def took_over(r):
        t = since.get(r)
        if t is None:
            return ', its law never took over' if r in since else ''
        return f', law from {(t - t_first) / 60:.0f} min' if t_first is not None else ''
    print(f'Each robot against its animal (every statistic within {100 * v["bar"]:.0f} %; '
          f'where it stood when its law took over): '
          + ', '.join(f'{r} ({e["animal"]}, started {e["start_offset_m"]:.1f} m off'
                      f'{took_over(r)}) '
                      f'{"pass" if e["pass"] else "FAIL"}' for r, e in v['robots'].items())
          + f'; herd {"pass" if v["herd_pass"] else "FAIL"}')
    sk = summary['prediction_skill']
    print(f'One-step predictions of the live estimator over the second half '
          f'({sk["samples"]} animal-ticks), RMS: model {sk["model"]:.3f} m, constant velocity '
          f'{sk["constant_velocity"]:.3f} m, stay-put {sk["stay_put"]:.3f} m, damping only '
          f'{sk["damping_only"]:.3f} m')
    print(f'report: {args.out}/fig_params.png, fig_trajectories.png, fig_statistics.png, '
          f'summary.json, herd_poses.csv, herd_predictions.csv; learned model: '
          f'{summary["model_file"]}; herd file (for ros2 launch herd_ros herd.launch.py '
          f'herd:=...): {args.out}/herd.yaml')
    return 0


def run_herding(args) -> int:
    """``herd-ros demo --herding``: the herding graph live (:mod:`herd_ros.cli.herding_demo`)."""
    from herd_ros.cli.herding_demo import run_herding_demo
    if args.offline or args.bag or args.herd:
        raise HerdInputError('--herding runs simulated animals: no --offline, --bag or --herd')
    rate = 20.0 if args.rate is None else args.rate
    if not rate > 0:
        raise HerdInputError(f'--rate must be positive, got {rate}')
    if args.animals < 2 or args.herders < 1:
        raise HerdInputError('--animals must be at least 2 and --herders at least 1')
    s = run_herding_demo(args.out, n_animals=args.animals, herders=args.herders, rate=rate,
                         seed=args.seed, herder=args.herder,
                         model_warmup=args.model_warmup)
    verdict = (f'the herd is inside the goal after {s["time_s"]:.0f} s' if s['success'] else
               f'the herd is not home within {s["budget_s"]:.0f} s '
               f'({s["final_inside"]} of {s["n_animals"]} inside)')
    print(f'\nherding done in {s["wall_time_s"]:.0f} s: {verdict} (simulated time). Report: '
          f'{args.out}/herding.png, summary.json, herding_herd.csv, herding_robots.csv')
    return 0 if s['success'] else 1


def run_offline(args) -> int:
    """``herd-ros demo --offline``: ingest, batch fit, validation, simulation and the paper's
    figures."""
    from herd_ros.cli.main import main as cli
    t0 = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    bag = Path(args.bag) if args.bag else shipped_bag()
    traj = out / 'cows_filtered.csv'
    model = out / 'cows_model.yaml'
    steps = [
        ('ingest', ['ingest', str(bag), '-o', str(traj)]
         + (['--dt', str(args.dt)] if args.dt else [])),
        ('fit', ['fit', str(traj), '-o', str(model), '--grid', args.grid,
                 '--report', str(out / 'report'), '--seed', str(args.seed)]),
        ('simulate', ['simulate', str(model), '--steps', '360', '--initial', str(traj),
                      '--seed', str(args.seed), '-o', str(out / 'cows_simulated.csv')]),
    ]
    for k, (name, argv) in enumerate(steps, start=1):
        print(f'\n[{k}/{len(steps)}] herd-ros {" ".join(argv)}', flush=True)
        status = cli(argv)
        if status:
            return status
    summary = json.loads((out / 'report' / 'summary.json').read_text())
    one = summary['one_step_rms']
    print(f'\ndemo done in {time.perf_counter() - t0:.1f} s. One-step RMS on '
          f'{summary["evaluated_on"]} data: '
          f'model {one["model"]["herd"]:.2f} m, constant velocity '
          f'{one["constant_velocity"]["herd"]:.2f} m, stay-put {one["stay_put"]["herd"]:.2f} m, '
          f'damping only {one["damping_only"]["herd"]:.2f} m '
          f'(selected terms: {summary["selection"]["terms"]}).')
    print(f'figures: {out / "report"}/*.png; model: {model}')
    return 0
