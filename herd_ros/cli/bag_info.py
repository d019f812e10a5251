"""`herd-ros bag-info BAG`: storage, duration, topics with types and message counts."""
from __future__ import annotations

HELP = 'summarise a rosbag2: storage, duration, topics, types, counts'


def add_arguments(parser):
    parser.add_argument('bag', metavar='BAG', help='rosbag2 directory or .mcap file')


def run(args) -> int:
    from herd_ros.io.bags import bag_info
    print(bag_info(args.bag))
    return 0
