"""`herd-ros ingest DATA -o traj.csv [--dt S]`: GPS fixes -> filtered trajectory on one clock.

DATA is a GPS CSV, Movebank CSV, GPX file, rosbag2 directory or ``.mcap`` file. The path is
:func:`herd_ros.ingest.pipeline.trajectory_from_fixes`: exact WGS84 -> ENU about the datum,
one Kalman filter per collar with gating, the herd clock, an optional smoother. Prints the
datum, the per-collar counters, the collars whose refused fixes outlasted ``stale_after``
and the tracking score (the collar track, and the written file read as a user would,
against the last raw fix); writes the trajectory CSV of doc/formats.md and, beside it, the
per-collar table ``<out>.collars.csv``.
"""
from __future__ import annotations

from pathlib import Path

from herd_ros.errors import HerdInputError

HELP = 'filter GPS fixes (CSV, Movebank, GPX or bag) onto one clock: a trajectory CSV'
#: the process keeps the memory it frees (:mod:`herd_ros.process_memory`)
KEEPS_FREED_MEMORY = True


def parse_datum(text: str | None):
    """``LAT,LON[,ALT]`` -> tuple, or None."""
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(','))
    except ValueError:
        raise HerdInputError(f'--datum {text!r} is not LAT,LON[,ALT] numbers') from None
    if len(values) not in (2, 3):
        raise HerdInputError(f'--datum {text!r} needs 2 or 3 numbers: LAT,LON[,ALT]')
    return values


def add_filter_arguments(parser):
    """The filter options shared by `ingest` and `fit` (names as the node parameters)."""
    g = parser.add_argument_group('GPS filter (gps_ingest parameters)')
    g.add_argument('--datum', default=None, metavar='LAT,LON[,ALT]',
                   help='ENU origin; default: the first valid fix')
    g.add_argument('--motion-model', choices=('auto', 'fit', 'fixed'), default='auto',
                   help='fit: each collar\'s movement model (an integrated Ornstein-'
                        'Uhlenbeck velocity, random walk to constant velocity) and fix std '
                        'refitted by maximum likelihood as its fixes arrive, the walk of '
                        '--walk-accel-std its prior and walk component; fixed: the model of '
                        '--accel-std for every collar; auto (default): fit unless '
                        '--accel-std or --velocity-tau is given')
    g.add_argument('--accel-std', type=float, default=None,
                   help='white-noise acceleration std of the fixed motion model (m/s^2); '
                        'default 0.05')
    g.add_argument('--velocity-tau', type=float, default=None,
                   help='velocity correlation time (s) of the correlated random walk; '
                        '0 = constant velocity; default 120')
    g.add_argument('--walk-accel-std', type=float, default=None,
                   help='white-noise acceleration std (m/s^2) of the walk, the broad '
                        'component of a fitted collar\'s graze/walk mixture and its prior '
                        'until the first fit; default 0.1 (a walking animal, ~1 m/s)')
    g.add_argument('--refit-lag', type=float, default=None, metavar='S',
                   help='with the fitted motion model: data time (s) from a collar\'s refit '
                        'point to the first fix its new model filters (as the node\'s '
                        'refit_lag_s); default: 6 ms per collar (60 s for 10 000)')
    g.add_argument('--walk-probability', type=float, default=0.05,
                   help='prior probability per fix that a fitted collar walks (moves by the '
                        'broad model above rather than its own)')
    g.add_argument('--default-position-std', type=float, default=5.0,
                   help='fix std (m) when the covariance type is UNKNOWN')
    g.add_argument('--position-std-floor', type=float, default=0.5,
                   help='smallest fix std (m) ever trusted (floors zero covariances)')
    g.add_argument('--gate-probability', type=float, default=0.999,
                   help='Mahalanobis gate: chi-square(2) probability mass accepted')
    g.add_argument('--max-speed', type=float, default=3.0,
                   help='speed gate (m/s) against the last accepted fix')
    g.add_argument('--stale-after', type=float, default=None,
                   help='seconds without an accepted fix before a collar is missing (NaN) '
                        '(default: 3 x the 90th percentile fix interval, at least 30 s)')


def filter_kwargs(args) -> dict:
    """The filter parameters given on the command line (None = from the data)."""
    return dict(motion_model=args.motion_model, walk_probability=args.walk_probability,
                walk_accel_std=args.walk_accel_std,
                accel_std=args.accel_std, velocity_tau=args.velocity_tau,
                default_position_std=args.default_position_std,
                position_std_floor=args.position_std_floor,
                gate_probability=args.gate_probability, max_speed=args.max_speed,
                stale_after=args.stale_after, refit_lag_s=args.refit_lag)


def add_arguments(parser):
    """The verb's options (``herd-ros VERB --help``)."""
    parser.add_argument('data', metavar='DATA',
                        help='GPS CSV, Movebank CSV, GPX, rosbag2 directory or .mcap file')
    parser.add_argument('-o', '--output', required=True, help='trajectory CSV to write')
    parser.add_argument('--dt', type=float, default=None,
                        help='clock step (s) of the track; default: the largest round step '
                             'not above the 10th percentile of the fix intervals nor below '
                             'a tenth of their median (a tick between nearly any two fixes, '
                             'so each fix is in the track within a step)')
    parser.add_argument('--smoother', choices=('none', 'rts', 'lag', 'fir'), default='none',
                        help='none: causal filter (as the node); rts: Rauch-Tung-Striebel; '
                             'lag: fixed-lag smoother (each tick given the next --lag fixes); '
                             'fir: the paper\'s causal Gaussian FIR (n 30, sigma 6)')
    parser.add_argument('--lag', type=int, default=3,
                        help='fixes of delay of the fixed-lag smoother (default 3)')
    parser.add_argument('--format', choices=('auto', 'gps', 'movebank', 'gpx', 'bag'),
                        default='auto', help='input format')
    add_filter_arguments(parser)


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.ingest.pipeline import (format_counters, load_fixes, track_dt,
                                          trajectory_from_fixes)
    from herd_ros.trajectory import write_trajectory_csv

    from herd_ros.data_sources import is_trajectory_csv, planar_fixes_from_runs
    from herd_ros.ingest.pipeline import collar_spans

    planar = args.format == 'auto' and is_trajectory_csv(Path(args.data))
    if planar:                      # irregular planar fixes (RTLS, UWB): no geodesy
        fixes = planar_fixes_from_runs(args.data)
        datum = None
    else:
        fixes = load_fixes(args.data, args.format)
        datum = parse_datum(args.datum)
    if args.lag < 0:
        raise HerdInputError(f'--lag must be >= 0 fixes, got {args.lag}')
    dt = args.dt if args.dt is not None else track_dt(fixes)
    traj = trajectory_from_fixes(fixes, dt, datum=datum, smoother=args.smoother,
                                 lag=args.lag, progress=True, **filter_kwargs(args))
    write_trajectory_csv(args.output, traj)
    lead, trail = traj.meta['trimmed']
    stale = traj.meta['stale']
    if planar:
        print('planar fixes (x, y in metres): no datum, no geodesy')
    else:
        lat, lon, alt = traj.meta['datum']
        print(f'datum: lat {lat:.9f} lon {lon:.9f} alt {alt:.3f} '
              f'({"given" if args.datum else "first valid fix"})')
    dt_how = 'given' if args.dt else 'the 10th percentile of the fix intervals, rounded down'
    print(f'clock: {traj.n_steps} ticks of {traj.meta["dt"]:g} s ({dt_how}), the union of '
          f'the {traj.n_agents} collars\' spans ({lead} empty leading, {trail} empty '
          f'trailing ticks cut); stale agent-ticks (NaN: before a collar\'s first fix, '
          f'after its last, or silent longer than '
          f'{traj.meta["filter_params"].stale_after:g} s): {int(stale.sum())} of {stale.size}')
    from herd_ros.ingest.pipeline import (PRINTED_COLLARS, collar_table,
                                          format_motion_fits, format_refusal_runs, lost_most,
                                          refusal_runs)
    counters, spans = traj.meta['counters'], collar_spans(traj)
    fits = traj.meta.get('motion_fits')
    refusals = refusal_runs(traj.meta['raw_fixes'], traj.meta['timelines'],
                            traj.times[0] if len(traj.times) else 0.0)
    table_path = Path(args.output).with_suffix('.collars.csv')
    collar_table(counters, spans, fits, refusals).to_csv(table_path, index=False,
                                                         float_format='%.6g')
    if len(counters) > PRINTED_COLLARS:
        shown = lost_most(counters, 10)
        total = {k: sum(c.get(k, 0) for c in counters.values()) for k in
                 ('accepted', 'rejected_no_fix', 'rejected_nan', 'rejected_time',
                  'rejected_gate', 'rejected_speed', 'rejected_range',
                  'rejected_unconfirmed')}
        print(f'{len(counters)} collars: ' + ', '.join(
            f'{k.replace("rejected_", "")} {v}' for k, v in total.items())
            + f'; the {len(shown)} that lost the most fixes:')
        print(format_counters(shown, spans))
    else:
        print(format_counters(counters, spans))
        if fits is not None:
            print(format_motion_fits(fits))
    line = format_refusal_runs(refusals, traj.meta['filter_params'].stale_after)
    if line:
        print(line)
    from herd_ros.ingest.tracking_score import (format_ingest_tracking_score,
                                                ingest_tracking_score)
    # the written track scored as a user would score it (causal only without a smoother)
    clock = (traj.times, traj.positions, traj.agents) if args.smoother == 'none' else None
    print(format_ingest_tracking_score(ingest_tracking_score(
        traj.meta['raw_fixes'], traj.meta['timelines'], clock=clock)))
    print(f'wrote {args.output} (smoother: {args.smoother}) and, per collar, what was kept '
          f'and why anything was not: {table_path}')
    return 0
