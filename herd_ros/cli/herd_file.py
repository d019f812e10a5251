"""`herd-ros herd-file`: write the herd file of a recording (what the live demo derives).

The herd file (:mod:`herd_ros.herd_file`) holds everything herd-specific about the live
graph: agents, datum, clock step, field grid and bounds, fence, robots, replay rate.
``herd-ros demo --herd FILE`` and ``ros2 launch herd_ros herd.launch.py herd:=FILE`` both
run from it, so they cannot drift; edit it to fix a datum, a fence or the robots.
"""
from __future__ import annotations

from pathlib import Path

from herd_ros.errors import HerdInputError

HELP = 'write the herd file of a bag or GPS file (datum, clock, field, fence, robots)'


def add_arguments(p):
    """The verb's options (``herd-ros VERB --help``)."""
    p.add_argument('data', help='rosbag2 of NavSatFix on /herd/<agent>/fix, or a GPS CSV/GPX')
    p.add_argument('-o', '--out', default='herd.yaml', help='herd file to write')
    p.add_argument('--dt', type=float, default=None,
                   help='the model\'s step (s); default: the median fix interval, at least '
                        'the live demo\'s 5 s (/herd/poses ticks at a divisor of it)')
    p.add_argument('--rate', type=float, default=None,
                   help='replay speed-up; default: the bag plays in about four minutes')


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.herd_file import write_herd_file
    from herd_ros.herd_setup import LIVE_MIN_DT, herd_setup_from_fixes
    from herd_ros.ingest.pipeline import load_fixes
    from herd_ros.io.gps_files import sniff_format
    for name in ('dt', 'rate'):
        value = getattr(args, name)
        if value is not None and not value > 0:
            raise HerdInputError(f'--{name} must be positive, got {value}')
    data = Path(args.data)
    fixes = load_fixes(data)
    setup = herd_setup_from_fixes(fixes, dt=args.dt, rate=args.rate, min_dt=LIVE_MIN_DT)
    is_bag = sniff_format(data) == 'bag'
    path = write_herd_file(args.out, setup, data if is_bag else None, header=(
        f'Herd file of {data.name}, derived by herd-ros herd-file (the live demo\'s choices).\n'
        f'Run: herd-ros demo --herd {args.out}   or   ros2 launch herd_ros herd.launch.py '
        f'herd:={args.out}'))
    print(f'chosen from {data.name}:\n{setup.describe()}\nwrote {path}')
    return 0
