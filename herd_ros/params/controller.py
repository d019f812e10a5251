"""Parameters of the ``controller`` node: the one table its ROS parameters, their checks,
``config/controller.yaml`` and the documentation come from (:mod:`herd_ros.params`).

Three groups: :data:`COMMON` (every mode: the safety layer), :data:`HERD_MODEL`
(mode herd_model) and :data:`FLOCKING` (mode flocking, shown in ``config/flocking.yaml``
with the gains of the ``flocking:`` block, which :class:`~herd_ros.flocking.olfati_saber
.FlockingParams` reads)."""
import dataclasses

from herd_ros.params import NodeTable, Param

HEADER = ('# controller: drives its robots with a control mode through an always-on safety '
          'layer.\n'
          '# Subscribes /fleet/<robot>/odom (robots and other_robots), publishes '
          '/fleet/<robot>/cmd_vel\n'
          '# (body frame) for its own robots only, and /diagnostics.\n'
          '# Every parameter below is shown with its default. With a model file from '
          '`herd-ros fit`\n'
          "# or the estimator's ~/save_model:\n"
          '#   ros2 run herd_ros controller --ros-args --params-file model.yaml \\\n'
          '#        --params-file config/controller.yaml\n')

COMMON = {
    'robots': Param(
        ['robot_1', 'robot_2', 'robot_3'],
        'robots this controller commands (names as in fleet_sim)',
        doc='Robots this controller commands (names as in fleet_sim).'),
    'other_robots': Param(
        [],
        'robots only watched (neighbours, never commanded)',
        example=['robot_4'],
        commented=True,
        doc=('\n'
             'Robots it only watches: they count as neighbours (mode '
             'herd_model: pair forces) but are\n'
             'never commanded (e.g. driven by another controller). Default: '
             'none.')),
    'mode': Param(
        'herd_model',
        'control mode',
        choices=('herd_model', 'flocking', 'imitation', 'herding'),
        doc=('\n'
             'Control mode: herd_model (follow the learned herd law), flocking '
             '(Olfati-Saber/La-Sheng\n'
             'target tracking: gains in config/flocking.yaml), imitation '
             '(learned swarm policies from\n'
             'a `herd-ros imitate` policy file passed with --params-file), herding '
             '(drive the animals of\n'
             '/herd/poses into a goal circle: config/herding.yaml).')),
    'rate_hz': Param(
        10.0,
        'command rate (Hz, node clock)',
        range=(1e-06, 1000.0),
        live=True,
        doc=('\n'
             'Command rate (Hz) on the node clock. The herd law is advanced by '
             'h/dt of a model step\n'
             "per tick (h = 1/rate_hz, dt = the model's step), so any rate "
             'follows the same law.')),
    'max_speed': Param(
        1.0,
        'speed limit (m/s) of every command',
        range=(1e-06, 100.0),
        live=True,
        doc=('\n'
             'Speed limit (m/s) of every command (direction kept when limiting).')),
    'kinematics': Param(
        'holonomic',
        'robot kinematics (as in fleet_sim)',
        choices=('holonomic', 'unicycle'),
        doc=('\n'
             'Kinematics of the robots (as in fleet_sim): holonomic gets '
             'linear.x/y in the body\n'
             'frame; unicycle gets linear.x and angular.z from a heading '
             'controller.')),
    'heading_gain': Param(
        2.0,
        'unicycle: yaw rate per rad of heading error (1/s)',
        range=(1e-06, 1000.0),
        doc=('\n'
             'Unicycle heading controller: yaw rate = heading_gain (1/s) x '
             'heading error, limited to\n'
             'max_yaw_rate (rad/s).')),
    'max_yaw_rate': Param(
        2.0,
        'unicycle: yaw-rate limit (rad/s)',
        range=(1e-06, 1000.0)),
    'fence': Param(
        [],
        'fence polygon x1, y1, x2, y2, ... (m, map); no command crosses it',
        example=[-50.0, -50.0, 50.0, -50.0, 50.0, 50.0, -50.0, 50.0],
        commented=True,
        doc=('\n'
             "Fence polygon x1, y1, x2, y2, ... (m, map frame). No command's "
             'path over\n'
             'safety_horizon_s crosses it; robots stop fence_margin (m) short '
             'of it along their path.\n'
             'Set fence_margin >= max_speed² / (2 max_accel) of the robots so '
             'braking fits.\n'
             'Default: no fence.')),
    'fence_margin': Param(
        0.5,
        'robots stop this far (m) short of the fence',
        range=(0.0, 1000000.0),
        live=True),
    'safety_horizon_s': Param(
        1.0,
        ('horizon (s) over which a command is checked against fence and '
         'obstacles'),
        range=(1e-06, 1000000.0),
        doc=('\n'
             'Horizon (s) over which a command is assumed held when checked '
             'against fence and\n'
             "obstacles (at least one period). Default 1 s = fleet_sim's "
             'cmd_timeout_s, so even a\n'
             'controller that dies mid-command cannot send a robot across the '
             'fence.')),
    'obstacles': Param(
        [],
        'circular obstacles x, y, r (m) no command may enter',
        example=[10.0, 5.0, 2.0],
        commented=True,
        doc=('\n'
             'Circular obstacles x, y, r (m) that no command may enter '
             '(inflated by fence_margin).')),
    'odom_timeout_s': Param(
        0.5,
        'a robot with older odometry (s) gets a zero command',
        range=(1e-06, 1000000.0),
        live=True,
        doc=('\n'
             'A robot whose odometry is older than this (s, node clock, time of '
             'receipt) gets an\n'
             'explicit zero Twist on the next tick and exerts no force on the '
             'others.')),
    'startup_wait_s': Param(
        5.0,
        'at start, wait this long (s) for every robot to report before driving any',
        range=(0.0, 1000000.0),
        doc=('\n'
             'The fleet starts together: no robot is driven (zero Twists) until every '
             'robot in\n'
             'robots has reported its odometry once, or this long (s, node clock) after '
             'the first\n'
             'did; a robot heard later joins then (herd_ros/control/fleet_start.py). 0: '
             'start with\n'
             'the first robot heard.')),
    'diagnostics_period_s': Param(
        1.0,
        'period (s) of /diagnostics',
        range=(0.001, 3600.0),
        doc=('\n'
             'Period (s) of /diagnostics.')),
}

HERD_MODEL = {
    'assignment': Param(
        [],
        'the animal each robot imitates; empty = robot k takes agent k mod N',
        example=['cow_1', 'cow_2', 'cow_3'],
        commented=True,
        doc=('\n'
             '---- mode herd_model '
             '-----------------------------------------------------------------\n'
             'The animal each robot imitates, one per robot (and '
             'other_assignment one per\n'
             'other_robot). Empty: robot k (robots then other_robots) takes the '
             "model's agent\n"
             'k mod N.')),
    'other_assignment': Param(
        [],
        'the animal of each other_robot',
        example=['cow_1'],
        commented=True),
    'noise': Param(
        False,
        "draw the law's noise w of the assigned animal (N(0, Q), or its noise regimes)",
        doc=('\n'
             "Draw the law's noise w of the assigned animal, and its seed: N(0, Q_i), "
             'or its stop-and-go\n'
             'noise regimes where the model file has them or the estimator '
             'publishes them\n'
             '(/herd/model/noise and /herd/model/noise_regimes with model_source '
             'topic).')),
    'seed': Param(
        0,
        'seed of the noise generator',
        range=(0, 2147483647)),
    'match_pace': Param(
        True,
        "topic, with noise: scale each robot's noise so its speed matches its animal's",
        doc=('\n'
             "With noise and model_source topic: scale each robot's noise so that "
             'its speed at the\n'
             "model's step matches its animal's on /herd/poses over the last 240 "
             'ticks (the law\'s\n'
             "noise, estimated from the track, carries the collar's error; "
             'herd_ros/control/pace_match.py).')),
    'match_place': Param(
        True,
        "topic: each robot's place pull made to hold it as its animal keeps its place",
        doc=('\n'
             'With model_source topic: the share of each robot\'s place pull it also feels '
             'inside\n'
             "its range, corrected so that its offset from the other robots' centroid "
             'spreads as\n'
             "its animal's does on /herd/poses (0: the pull at the range's edge only; "
             'herd_ros/control/place_match.py).')),
    'model_source': Param(
        'file',
        'model.* parameters of a model file, or live from /herd/model/params',
        choices=('file', 'topic'),
        doc=('\n'
             'Where the model comes from:\n'
             '  file  - the model.* parameters of a model file given with '
             '--params-file;\n'
             '  topic - live from /herd/model/params (estimator, '
             'Float64MultiArray agent x param, rows\n'
             '          [damping, theta1.., theta2.., field_u.., field_v..]), read '
             'with the estimator\'s\n'
             '          latched /herd/model/structure (its agents, dt, law, field '
             'grid, profile: the\n'
             '          controller declares none of them). The field is on every '
             'centre of the grid\n'
             '          (zero where the animal has not been), sigma = 2/3 of the grid '
             'spacing, neighbours =\n'
             '          the other agents in order. Q_i for the noise comes from '
             '/herd/model/noise, each\n'
             '          animal\'s home pull from /herd/model/home, its place in the '
             'herd from\n'
             '          /herd/model/place.\n'
             'Either way a model with a damping |a| >= 1 (unstable law) is '
             'refused: from a file at\n'
             'start, from the topic by keeping the previous model; -1 < a < 0 '
             '(the velocity\n'
             'reverses every step, what a fit on noisy positions at a coarse '
             'clock learns) is\n'
             'followed with a warning. Adopting and refusing are logged.')),
    'model_min_updates': Param(
        0,
        'topic: ignore the first N model updates; a robot waits for N model steps of its animal',
        range=(0, 1000000000),
        doc=("topic only: ignore the first N model updates (an estimator's "
             'first estimates are poor;\n'
             'robots wait until a model is accepted); and a robot waits (wait_mode) until '
             'its animal\n'
             'has been on /herd/poses in N model steps (a collar that starts late has a young '
             'law).')),
    'wait_mode': Param(
        'escort',
        "topic: what a robot does while it waits for its animal's law",
        choices=('escort', 'hold'),
        doc=('\n'
             'With model_source topic, while a robot waits (model_min_updates): escort goes to '
             'its\n'
             "animal's latest pose on /herd/poses (v = u + (a - p)/tau, tau the herd clock's "
             'step,\n'
             'u its velocity, capped by the safety layer), so\n'
             'that its law starts where its animal is; hold stands still where it is '
             '(herd_ros/control/escort.py).\n'
             "escort drives a robot onto its animal's position: for robots in the same field "
             'as the animals, use hold.')),
}

FLOCKING = {
    'target_source': Param(
        'herd_centroid',
        ('where the target comes from: the centroid of /herd/poses or a '
         'PointStamped topic'),
        choices=('herd_centroid', 'point'),
        doc=('\n'
             'Where the target comes from: herd_centroid (centroid of the '
             'geometry_msgs/PoseArray\n'
             '/herd/poses, NaN poses ignored) or point (a '
             'geometry_msgs/PointStamped topic). Both in\n'
             'the map frame. The target velocity is the finite difference of '
             'the last two fixes over\n'
             'their header stamps.')),
    'target_topic': Param(
        '',
        'topic of the target; empty = /herd/poses for herd_centroid',
        doc=('Topic of the target; empty = /herd/poses for herd_centroid '
             '(required for point).')),
    'target_timeout_s': Param(
        2.0,
        'a target silent this long (s) is held still',
        range=(1e-06, 1000000.0),
        doc=('A target silent for longer than this (s, node clock) is held '
             'still (velocity 0).')),
    'integration_step_s': Param(
        0.01,
        'largest integration substep (s) of the flocking law',
        range=(1e-06, 1.0),
        doc=('Largest integration substep (s) of the double-integrator law '
             'inside one control\n'
             "period (0.01 s = the offline simulator's 100 Hz). The stiff β and "
             'α consensus terms\n'
             'need h·c2 well below 2; do not raise it above ~0.02 s.')),
}

TABLE = NodeTable('controller', HEADER, {**COMMON, **HERD_MODEL})

FLOCKING_HEADER = ('# Flocking mode of the controller: Olfati-Saber (2006) α/β/γ flocking '
                   'with La & Sheng (2009)\n'
                   '# centre-of-mass feedback, as evaluated in the report "Decentralized '
                   'Flocking Control for\n'
                   '# Dynamic Object Tracking". Equations: '
                   'herd_ros/flocking/olfati_saber.py.\n'
                   '# Use: ros2 run herd_ros controller --ros-args --params-file '
                   'config/flocking.yaml \\\n'
                   '#          -p robots:=[robot_1, robot_2, robot_3]\n'
                   '#      herd-ros flock --params config/flocking.yaml --scenario free '
                   '--out out/\n'
                   '#      (the flock verb reads only the flocking: block)\n'
                   '# Units: metres, seconds; c1 gains in 1/s², c2 gains in 1/s.\n'
                   '# The robots take velocity commands; the controller integrates the '
                   "law's acceleration into\n"
                   '# the commanded velocity every period in substeps of at most '
                   'integration_step_s (see\n'
                   '# herd_ros/control/flocking_command.py). The safety layer of '
                   'config/controller.yaml\n'
                   '# (max_speed, fence, obstacles, odom_timeout_s) applies as in every '
                   'mode.\n'
                   "# The report's gains below are for its 50-agent, 10 m/s setting: the "
                   'linear target pull\n'
                   '# c1_gamma·‖q − q_r‖ then dominates the bounded α repulsion and '
                   'compresses a small flock\n'
                   '# (robots can meet); for a few slow robots use a weaker pull, e.g. '
                   'c1_gamma 2, c1_com 1\n'
                   '# (with c2 = 2√c1), as test/test_controller_modes.py does.\n')

FLOCKING_TAIL = ('\n'
                 '    flocking:\n'
                 '      # --- α: agent–agent lattice and velocity consensus '
                 '-------------------------------------\n'
                 '      # Gain of the σ-norm gradient between neighbours (attraction beyond '
                 '`distance`,\n'
                 '      # repulsion inside). The report: 5. Raise for a tighter lattice; it '
                 'must stay below\n'
                 '      # c1_gamma and c1_beta (Olfati-Saber: c1α < c1γ < c1β) or obstacles '
                 'lose.\n'
                 '      c1_alpha: 5.0\n'
                 '      # Gain of velocity consensus with neighbours, 2·√c1_alpha (critical '
                 'damping). Raising it\n'
                 '      # with many neighbours can make the discrete loop unstable '
                 '(c2·degree·dt < 2).\n'
                 '      c2_alpha: 4.47213595499958\n'
                 '      # Interaction range r (m): neighbours are the agents closer than '
                 'this. The report: 9.\n'
                 '      # Set it to what the robots can actually sense/communicate.\n'
                 '      range: 9.0\n'
                 '      # Desired spacing d (m) of the α-lattice. The paper keeps r = 1.2 '
                 'd; the report fixes\n'
                 '      # r = 9 only, so d = 9/1.2 = 7.5. Must be smaller than range.\n'
                 '      distance: 7.5\n'
                 '      # σ-norm parameter ε (Olfati-Saber 2006 §VIII: 0.1). Smaller ε '
                 'makes the σ-norm closer\n'
                 '      # to the Euclidean norm and the gradient stiffer at long range.\n'
                 '      epsilon: 0.1\n'
                 '      # Bump function h of the α adjacency a_ij and of φ_α (Olfati-Saber '
                 '2006 §VIII: 0.2):\n'
                 '      # weights are 1 up to h·r_α (σ-norm) and fall smoothly to 0 at r.\n'
                 '      h_alpha: 0.2\n'
                 '      # Action function φ(z) = ½[(a+b)σ1(z+c) + (a−b)], c = |a−b|/√(4ab) '
                 '(Olfati-Saber §VIII:\n'
                 '      # a = b = 5, an even pull/push). a > b strengthens attraction, b > '
                 'a repulsion.\n'
                 '      a: 5.0\n'
                 '      b: 5.0\n'
                 '\n'
                 '      # --- β: obstacle avoidance through virtual agents on obstacle '
                 'boundaries ----------------\n'
                 '      # Gain of the repulsion from β-agents. The report: 300. Lower it '
                 'and fast flocks may cut\n'
                 '      # into obstacles; raise it and agents bounce harder (keep c2_beta = '
                 '2·√c1_beta).\n'
                 '      c1_beta: 300.0\n'
                 '      c2_beta: 34.64101615137755\n'
                 "      # d' (m): distance kept from obstacle boundaries (Olfati-Saber "
                 "§VIII: d' = 0.6 d).\n"
                 '      beta_distance: 4.5\n'
                 "      # r' (m): β-agents farther than this are ignored (Olfati-Saber "
                 "§VIII: r' = 1.2 d').\n"
                 '      beta_range: 5.4\n'
                 '      # Bump h of φ_β and b_ik (Olfati-Saber 2006 §VIII: 0.9).\n'
                 '      h_beta: 0.9\n'
                 '      # Circular obstacles as triples x, y, r (m, frame `map`), e.g. '
                 '[100.0, 50.0, 10.0].\n'
                 '      # Default: none (a ROS parameters file cannot type an empty array, '
                 'so leave it out).\n'
                 '      # obstacles: [100.0, 50.0, 10.0]\n'
                 '\n'
                 '      # --- γ: navigation to the target '
                 '--------------------------------------------------------\n'
                 '      # Target feedback c1mt (report: 15) and its damping 2·√c1mt. Raise '
                 'for faster\n'
                 '      # tracking of a manoeuvring target; the flock is then compressed '
                 'harder around it.\n'
                 '      c1_gamma: 15.0\n'
                 '      c2_gamma: 7.745966692414834\n'
                 '      # Centre-of-mass feedback c1mc (report: 10) and its damping '
                 '2·√c1mc, used by the\n'
                 '      # global-com and local-com modes.\n'
                 '      c1_com: 10.0\n'
                 '      c2_com: 6.324555320336759\n'
                 '      # plain: each agent to the target; global-com: plus the whole '
                 "flock's centre of mass\n"
                 "      # (report eq. 5, needs every agent's state; adversaries drag it); "
                 'local-com: plus the\n'
                 "      # centre of mass of the agent's neighbourhood (eq. 6, "
                 'decentralized). Default local-com.\n'
                 '      gamma_mode: local-com\n')

#: config/flocking.yaml: the controller in mode flocking
FLOCKING_TABLE = NodeTable('controller', FLOCKING_HEADER, {
    'mode': dataclasses.replace(COMMON['mode'], example='flocking',
                                doc='Select this mode of the controller node.'),
    **FLOCKING}, FLOCKING_TAIL, file='flocking.yaml')

HERDING = {
    'goal': Param(
        [20.0, 20.0],
        'centre [x, y] (m, map) of the goal circle',
        doc=('\n'
             'Centre [x, y] (m, map frame) and radius (m) of the goal circle the '
             'animals are driven\n'
             'into; the herd is home when every animal of /herd/poses is inside.')),
    'goal_radius': Param(
        15.0,
        'radius (m) of the goal circle',
        range=(1e-06, 1e6)),
    'herder': Param(
        'strombom',
        "the herders' policy",
        choices=('strombom', 'model'),
        doc=('\n'
             "The herders' policy: strombom (Strömbom et al. 2014: collect the "
             "animal furthest from\n"
             "the herd's centre while the herd is not gathered, else drive from "
             'behind the centre;\n'
             'several robots collect the furthest few and drive from an arc, '
             'herd_ros/herding/strombom.py),\n'
             "or model (receding-horizon control over the animals' learned "
             'response to the robots,\n'
             'learned at start from simulated recordings of as many animals and '
             'robots, Strömbom\'s\n'
             'shepherd herding meanwhile, then refitted online from /herd/poses: '
             'herd_ros/herding/model_herder.py).')),
    'model_warmup': Param(
        'strombom',
        'herder model: what the robots do while the model herder learns',
        choices=('strombom', 'hold'),
        doc=('\n'
             'With herder model, what the robots do while the model herder learns '
             'its response (10-60 s\n'
             "of wall time by machine): strombom (Strömbom's shepherd herds "
             'meanwhile) or hold (they\n'
             'hold still, so that the model herder does all the herding).')),
    'herd_topic': Param(
        '/herd/poses',
        'PoseArray of the animals (map frame; NaN = missing)'),
    'herder_speed': Param(
        1.5,
        'speed (m/s) of a herder on its way (max_speed still caps it)',
        range=(1e-06, 1e3),
        doc=('\n'
             'Speed (m/s) of a herder on its way to its target (1.5 × the '
             "animals' in Strömbom's\n"
             'setting); the safety layer\'s max_speed still caps it.')),
    'animal_spacing': Param(
        2.0,
        "r_a (m): the animals' personal space",
        range=(1e-06, 1e6),
        doc=('\n'
             "r_a (m), the animals' personal space: the herd counts as gathered "
             'when every animal is\n'
             'within r_a N^(2/3) of its centre, the herders drive from r_a √N '
             'behind it and stand\n'
             'still within stop_factor × r_a of an animal (not to split the herd).')),
    'stop_factor': Param(
        3.0,
        'a herder stands still within this many r_a of an animal',
        range=(0.0, 1e3)),
    'drive_arc_deg': Param(
        30.0,
        'several herders drive from an arc of ± this many degrees',
        range=(0.0, 180.0)),
    'herder_noise': Param(
        0.3,
        "weight of a random direction in a herder's heading (Strömbom: 0.3)",
        range=(0.0, 100.0)),
    'herding_seed': Param(
        0,
        "seed of the herders' noise",
        range=(0, 2147483647)),
    'markers_period_s': Param(
        0.5,
        'period (s, node clock) of /herding/markers (goal, herd centre, targets)',
        range=(1e-03, 3600.0)),
}

HERDING_HEADER = ('# Herding mode of the controller: the robots drive the animals of '
                  '/herd/poses into a goal\n'
                  '# circle (Strömbom et al. 2014, J. R. Soc. Interface 11:20140719). '
                  'RViz markers of the goal,\n'
                  "# the herd's centre and each robot's target on /herding/markers. "
                  'The safety layer of\n'
                  '# config/controller.yaml applies as in every mode. Use:\n'
                  '#   ros2 launch herd_ros herding.launch.py     (animals, robots and '
                  'this controller)\n'
                  '#   ros2 run herd_ros controller --ros-args --params-file '
                  'config/herding.yaml\n')

#: config/herding.yaml: the controller in mode herding
HERDING_TABLE = NodeTable('controller', HERDING_HEADER, {
    'mode': dataclasses.replace(COMMON['mode'], example='herding',
                                doc='Select this mode of the controller node.'),
    'max_speed': dataclasses.replace(COMMON['max_speed'], example=1.5,
                                     doc='Speed limit (m/s): at least herder_speed.'),
    **HERDING}, file='herding.yaml')
