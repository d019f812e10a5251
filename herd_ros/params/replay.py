"""Parameters of the ``replay`` node: the one table its ROS parameters, their checks,
``config/replay.yaml`` and the documentation come from (:mod:`herd_ros.params`)."""
from herd_ros.params import NodeTable, Param

HEADER = ('# replay: plays a rosbag2 (mcap or sqlite3) onto its topics with the recorded '
          'timing.\n'
          '# Messages are republished as the CDR bytes stored in the bag (no conversion). '
          'The process\n'
          '# exits with status 0 at the end of the bag (unless loop), status 2 on a bad '
          'parameter.\n'
          '# Every parameter below is shown with its default. Run:\n'
          '#   ros2 run herd_ros replay --ros-args --params-file config/replay.yaml -p '
          'bag:=my_bag\n')

PARAMS = {
    'bag': Param(
        '',
        ('rosbag2 directory (metadata.yaml) or bare .mcap file to play '
         '(required)'),
        doc=('Path of a rosbag2 directory (with metadata.yaml) or of a bare '
             '.mcap file. Required.')),
    'rate': Param(
        1.0,
        'playback speed-up: bag gaps are divided by rate',
        range=(1e-06, 1000000.0),
        live=True,
        doc=('\n'
             'Playback speed: bag gaps are divided by rate (10.0 = ten times '
             'faster). > 0.\n'
             'Every message is scheduled against the instant the pass started, '
             'so sleep errors\n'
             'never accumulate; measured publish-time error: median 0.03-0.4 ms '
             'at rate 10.')),
    'loop': Param(
        False,
        'start again from start_offset at the end of the bag',
        doc=('\n'
             'Start again from start_offset when the end is reached (the /clock '
             'jumps back).')),
    'start_offset': Param(
        0.0,
        'skip the first start_offset s of the bag',
        range=(0.0, 1000000000000.0),
        doc=('\n'
             'Skip the first start_offset seconds of the bag (measured from the '
             'first message of\n'
             "the whole bag, on the bag's receive-time axis).")),
    'topics': Param(
        [],
        'topics to play; empty = every topic',
        example=['/herd/cow_1/fix', '/herd/cow_2/fix'],
        commented=True,
        doc=('\n'
             'Topics to play; empty (unset) = every topic of the bag. A name '
             'not in the bag is an\n'
             'error. ROS parameter files cannot hold an empty list, so the '
             'default is left unset:')),
    'remap': Param(
        [],
        "rename topics on output, 'old:=new'",
        example=['/herd/cow_1/fix:=/herd/test_cow/fix'],
        commented=True,
        doc=('\n'
             "Rename topics on output, entries 'old:=new' (quote them: YAML "
             "reads ':' specially).")),
    'publish_clock': Param(
        True,
        'publish the bag time on /clock',
        doc=('\n'
             'Publish rosgraph_msgs/Clock on /clock carrying the bag time (just '
             'before each\n'
             'message and at clock_rate_hz wall in between), so use_sim_time '
             'nodes follow the bag.')),
    'clock_rate_hz': Param(
        100.0,
        '/clock messages per second of wall time between messages',
        range=(0.001, 10000.0)),
    'qos_from_bag': Param(
        True,
        'offer the QoS recorded in the bag',
        doc=('\n'
             'Offer the QoS recorded in the bag (offered_qos_profiles: '
             'reliability, durability,\n'
             'history, depth ≥ default_qos_depth) when the bag has it for a '
             'topic.')),
    'default_qos': Param(
        'reliable',
        'QoS of topics without a recorded profile',
        choices=('reliable', 'sensor_data'),
        doc=('\n'
             "QoS for topics without a recorded profile: 'reliable' (reliable, "
             'volatile, keep last\n'
             "default_qos_depth) or 'sensor_data' (best effort, depth 5). "
             'Reliable is the default,\n'
             'also for NavSatFix: a reliable publisher serves reliable and '
             'best-effort subscribers\n'
             'alike, a best-effort one only the latter, and a replay should not '
             'drop fixes.')),
    'default_qos_depth': Param(
        100,
        'history depth of reliable topics without a profile',
        range=(1, 1000000)),
    'wait_for_subscribers': Param(
        0,
        ('before playing, wait for this many subscribers on every topic (0 = '
         'start at once)'),
        range=(0, 1000),
        doc=('\n'
             'Before playing, wait until every played topic has at least this '
             'many subscribers\n'
             '(0 = start at once). Useful in scripts and tests so the first '
             'messages are not\n'
             'published before the subscribers are matched.')),
    'progress_period_s': Param(
        5.0,
        'period (s, wall) of the progress line',
        range=(0.001, 1000000.0),
        live=True,
        doc=('\n'
             'Progress line in the log every progress_period_s of wall time.')),
    'exit_when_done': Param(
        True,
        'end the process (status 0) at the end of the bag',
        doc=('\n'
             'At the end of the bag (without loop), shut the process down (exit '
             'status 0). A graph\n'
             'composed in one process (herd-ros demo) sets false and stops the '
             'graph itself.')),
}

TABLE = NodeTable('replay', HEADER, PARAMS)


def parse_remap(rules) -> dict[str, str]:
    """``['old:=new', ...]`` -> ``{old: new}``."""
    from herd_ros.params import ParameterError
    out = {}
    for rule in rules:
        old, sep, new = rule.partition(':=')
        if not sep or not old.strip() or not new.strip():
            raise ParameterError(f'remap entries must read old:=new, got {rule!r}')
        out[old.strip()] = new.strip()
    return out


class ReplayConfig:
    """replay parameters (values checked against :data:`PARAMS`: types, ranges, choices)
    made into what the node runs with; :class:`~herd_ros.params.ParameterError` names what
    is wrong beyond the table's checks."""

    def __init__(self, p: dict):
        from herd_ros.params import ParameterError
        self.bag = str(p['bag']).strip()
        if not self.bag:
            raise ParameterError('bag: give the path of a rosbag2 directory or .mcap file')
        for name in ('rate', 'clock_rate_hz', 'progress_period_s', 'start_offset', 'loop',
                     'publish_clock', 'qos_from_bag', 'default_qos', 'default_qos_depth',
                     'wait_for_subscribers', 'exit_when_done'):
            setattr(self, name, p[name])
        self.topics = [str(t) for t in p['topics']]
        self.remap = parse_remap(p['remap'])
