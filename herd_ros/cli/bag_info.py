"""`herd-ros bag-info BAG`: storage, duration, topics with types and message counts."""
from __future__ import annotations

HELP = 'summarise a rosbag2: storage, duration, topics, types, counts'


def add_arguments(parser):
    """The verb's options (``herd-ros VERB --help``)."""
    parser.add_argument('bag', metavar='BAG', help='rosbag2 directory or .mcap file')


def run(args) -> int:
    """Run the verb on the parsed ``args``; returns the exit status."""
    from herd_ros.io.bags import bag_info
    print(bag_info(args.bag))
    return 0
