"""Parameters of the ``record`` node: the one table its ROS parameters, their checks,
``config/record.yaml`` and the documentation come from (:mod:`herd_ros.params`)."""
from herd_ros.params import NodeTable, Param

HEADER = ('# record: records named topics to a rosbag2 (mcap) that survives `kill -9`.\n'
          "# Each topic is subscribed when a publisher of it appears, with the publisher's "
          'type and a\n'
          '# matching QoS; messages are written as received (CDR bytes) with their receive '
          'time on the\n'
          '# node clock (use_sim_time: true records /clock time). SIGINT/SIGTERM close the '
          'bag\n'
          '# properly. Every parameter below is shown with its default. Run:\n'
          '#   ros2 run herd_ros record --ros-args --params-file config/record.yaml \\\n'
          '#       -p bag:=herd_bag -p "topics:=[/herd/cow_1/fix, /herd/cow_2/fix]"\n')

PARAMS = {
    'bag': Param(
        '',
        ('output bag directory (must not exist); empty = rosbag2_<date-time> in '
         'the working directory, as ros2 bag record names it'),
        doc=('Output bag directory (must not exist). Empty: '
             'rosbag2_YYYY_MM_DD-HH_MM_SS in the\n'
             'working directory, as `ros2 bag record` names it.')),
    'topics': Param(
        [],
        'topics to record (absolute names; required)',
        example=['/herd/cow_1/fix', '/herd/cow_2/fix'],
        commented=True,
        doc=('\n'
             'Topics to record (absolute names). Required; a list cannot be '
             'empty in a parameter\n'
             'file, so the default is left unset:')),
    'storage': Param(
        'mcap',
        'mcap (crash-safe) or sqlite3',
        choices=('mcap', 'sqlite3'),
        doc=('\n'
             'mcap (crash-safe, see flush_period_s) or sqlite3 (written at '
             'close: a killed\n'
             'recording is lost).')),
    'flush_period_s': Param(
        0.5,
        'mcap: s between flushes (a kill -9 loses at most this)',
        range=(0.001, 1000000.0),
        doc=('\n'
             'Crash safety (mcap): every flush_period_s, and every '
             'flush_messages messages, the\n'
             'messages so far are written as one chunk followed by a closing '
             'footer, and\n'
             'metadata.yaml (present from the start) is rewritten. `kill -9` '
             'therefore loses at\n'
             'most the last flush_period_s of messages and leaves a bag that '
             'rosbags, the mcap\n'
             'library and replay open as it is. Shorter = less to lose, more, '
             'smaller chunks.')),
    'flush_messages': Param(
        1000,
        'mcap: messages between flushes',
        range=(1, 1000000000)),
    'discovery_period_s': Param(
        0.2,
        's between checks for publishers of topics not yet subscribed',
        range=(0.001, 1000000.0),
        doc=('\n'
             'How often the graph is checked for publishers of topics not yet '
             'subscribed (s).')),
    'qos_depth': Param(
        1000,
        'subscription queue depth',
        range=(1, 10000000),
        doc=('\n'
             'Subscription queue depth (keep last). Reliable if every publisher '
             'is, transient local\n'
             "if every publisher is; the publishers' profiles are stored as "
             'offered_qos_profiles.')),
    'progress_period_s': Param(
        10.0,
        's (wall) between message counts in the log',
        range=(0.001, 1000000.0),
        doc=('\n'
             'Message counts in the log every progress_period_s (s).')),
}

TABLE = NodeTable('record', HEADER, PARAMS)
