"""Parameters of the ``herd_sim`` node: the one table its ROS parameters, their checks,
``config/herd_sim.yaml`` and the documentation come from (:mod:`herd_ros.params`)."""
from herd_ros.params import NodeTable, Param

HEADER = ('# herd_sim: simulated animals that flee the robots (Strömbom et al. 2014 sheep), '
          'for herding.\n'
          '# Subscribes /fleet/poses (every robot is a dog to them); publishes /herd/poses '
          '(PoseArray,\n'
          '# animals sheep_1..sheep_N in order), /diagnostics and, with publish_clock, '
          '/clock.\n'
          '# Every parameter below is shown with its default. Run:\n'
          '#   ros2 run herd_ros herd_sim --ros-args --params-file config/herd_sim.yaml\n')

PARAMS = {
    'n_animals': Param(
        14,
        'number of animals (named sheep_1 .. sheep_N in /herd/poses)',
        range=(2, 100000),
        doc='Number of animals; /herd/poses lists sheep_1 .. sheep_N in order.'),
    'start_center': Param(
        [100.0, 100.0],
        'centre [x, y] (m, map) of the square the animals start in',
        doc=('\n'
             'Centre [x, y] (m, map frame) and side (m) of the square the animals '
             'start in, placed\n'
             'uniformly at random (seed) with random headings.')),
    'start_box': Param(
        40.0,
        'side (m) of the start square',
        range=(0.0, 1e6)),
    'seed': Param(
        0,
        'seed of the animals\' start and noise',
        range=(0, 2147483647)),
    'n_neighbours': Param(
        0,
        'neighbours whose local centre an animal is drawn to; 0 = half the herd',
        range=(0, 100000),
        doc=('\n'
             "Cohesion: an animal is drawn to the local centre of its n nearest "
             "neighbours (Strömbom's n;\n"
             '0 = half the herd, a cohesive flock; a few = short-range cohesion, '
             'hard to herd).')),
    'noise': Param(
        0.3,
        'weight e of the random direction in each step (Strömbom: 0.3)',
        range=(0.0, 100.0)),
    'spacing': Param(
        2.0,
        'r_a (m): animals closer than this push apart',
        range=(1e-06, 1e6),
        doc=('\n'
             'r_a (m): animals closer than this push apart; the herders drive '
             'from r_a·√N behind\n'
             "the herd's centre and stop within 3 r_a of an animal (controller "
             'mode herding).')),
    'flight_distance': Param(
        65.0,
        'r_s (m): an animal flees a robot closer than this',
        range=(0.0, 1e6)),
    'speed': Param(
        1.0,
        'animal speed (m/s) when it moves',
        range=(0.0, 1e3)),
    'graze': Param(
        0.05,
        'probability per step that an animal no robot alarms takes a step',
        range=(0.0, 1.0)),
    'step_s': Param(
        1.0,
        'simulation step (s of node time)',
        range=(1e-03, 3600.0)),
    'robots_topic': Param(
        '/fleet/poses',
        'PoseArray of the robots the animals flee'),
    'frame_id': Param(
        'map',
        'frame of /herd/poses'),
    'publish_clock': Param(
        False,
        'drive /clock (simulated time) for a faster-than-real-time graph',
        doc=('\n'
             'Publish /clock: the node then drives simulated time, rate × faster '
             'than real time, in\n'
             'ticks of clock_step_s, and steps the animals every step_s of it '
             '(the other nodes run\n'
             'with use_sim_time: true). Off: the animals step on the node clock.')),
    'rate': Param(
        1.0,
        'with publish_clock: simulated seconds per wall second',
        range=(1e-03, 1e4)),
    'clock_step_s': Param(
        0.05,
        'with publish_clock: /clock tick (s of simulated time)',
        range=(1e-04, 10.0)),
    'clock_max_lead_s': Param(
        0.5,
        'with publish_clock: how far (s) the clock may run ahead of the robots\' poses',
        range=(0.0, 3600.0),
        doc=('\n'
             'With publish_clock: the clock waits while the newest robot poses '
             '(/fleet/poses stamps)\n'
             'lag it by more than this (s of simulated time), so a busy machine '
             'slows the simulation\n'
             'instead of leaving the robots behind the animals (0 = lockstep).')),
    'diagnostics_period_s': Param(
        1.0,
        'period (s) of /diagnostics',
        range=(0.001, 3600.0)),
}

TABLE = NodeTable('herd_sim', HEADER, PARAMS)
