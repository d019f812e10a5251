"""`herd-ros import SRC -o BAG`: GPS CSV, Movebank CSV or GPX -> rosbag2 of NavSatFix.

Each fix becomes a ``sensor_msgs/msg/NavSatFix`` on ``/herd/<agent>/fix`` with header stamp
= receive time = the fix time (:func:`herd_ros.io.bags.write_fix_bag`).
"""
from __future__ import annotations

HELP = 'convert a GPS CSV, Movebank CSV or GPX file to a rosbag2 of NavSatFix'


def add_arguments(parser):
    """The verb's options (``herd-ros VERB --help``)."""
    parser.add_argument('src', metavar='SRC', help='GPS CSV, Movebank CSV or GPX file')
    parser.add_argument('-o', '--output', required=True, metavar='BAG',
                        help='bag directory to create')
    parser.add_argument('--format', choices=('auto', 'gps', 'movebank', 'gpx'),
                        default='auto', help='input format')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                        help='rosbag2 storage plugin')


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.io.bags import bag_info, write_fix_bag
    from herd_ros.io.gps_files import read_fix_file, sniff_format
    from herd_ros.errors import HerdInputError

    fmt = sniff_format(args.src) if args.format == 'auto' else args.format
    if fmt == 'bag':
        raise HerdInputError(f'{args.src}: is already a bag')
    fixes = read_fix_file(args.src, fmt)
    write_fix_bag(args.output, fixes, storage=args.storage, progress=True)
    print(f'read {len(fixes)} fixes of {fixes["agent"].nunique()} agents ({fmt})')
    print(bag_info(args.output))
    return 0
