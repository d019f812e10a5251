"""Parameters of the ``gps_ingest`` node: the one table its ROS parameters, their checks,
``config/gps_ingest.yaml`` and the documentation come from (:mod:`herd_ros.params`)."""
from herd_ros.params import NodeTable, Param

HEADER = ('# gps_ingest: GPS collar fixes -> filtered /herd/<agent>/odom and one herd clock '
          '/herd/poses.\n'
          '#\n'
          '#   ros2 run herd_ros gps_ingest --ros-args --params-file config/gps_ingest.yaml\n'
          '#\n'
          '# Every parameter is listed with its default. The filter is the one `herd-ros '
          'ingest` runs\n'
          '# offline (herd_ros/ingest/collar_filter.py): with the same values both give the '
          'same numbers.\n')

PARAMS = {
    'agents': Param(
        [],
        ('collar ids in the order of /herd/poses; each subscribes '
         '/herd/<id>/fix and publishes /herd/<id>/odom (required)'),
        example=['cow_1', 'cow_2', 'cow_3'],
        doc=('Collar ids, in the order of /herd/poses. Each id subscribes '
             '/herd/<id>/fix and\n'
             'publishes /herd/<id>/odom, so it must be a valid ROS name (letter '
             'first, then letters,\n'
             'digits, underscores). Required: the node refuses to start without '
             'it.')),
    'datum': Param(
        [],
        ('ENU origin [lat, lon] or [lat, lon, alt] (deg, deg, m); empty = the '
         'earliest valid fix'),
        doc=('\n'
             'Origin of the local ENU frame `frame_id`: [lat, lon] or [lat, '
             'lon, alt] (degrees,\n'
             'metres above the WGS84 ellipsoid). Empty = the earliest-stamped '
             'VALID fix (status not\n'
             'NO_FIX, finite lat/lon), chosen once every collar has sent a '
             'valid fix (or after\n'
             'stale_after seconds of data time) and logged once. Set it '
             'explicitly whenever several\n'
             'runs, nodes or maps must share one frame (the fleet_sim datum, a '
             'paddock corner).')),
    'dt': Param(
        1.0,
        'herd clock step (s of data time) of /herd/poses',
        range=(0.001, 1000000.0),
        doc=('\n'
             'Step of the herd clock (s). /herd/poses is published once per '
             'tick k*dt of DATA time\n'
             "(the fixes' header stamps), never wall time. Use the collar fix "
             'interval (1 s for\n'
             '1 Hz collars; typical long-life collars report every 60-900 s) or '
             "the model's dt.")),
    'default_position_std': Param(
        5.0,
        'horizontal std (m) of a fix whose covariance is UNKNOWN',
        range=(0.001, 10000.0),
        doc=('\n'
             'Horizontal std (m) of a fix whose position_covariance_type is '
             'UNKNOWN. 5 m suits\n'
             'consumer GNSS collars under open sky (CEP 2-5 m); raise it under '
             'trees.')),
    'position_std_floor': Param(
        0.5,
        'smallest fix std (m) ever trusted',
        range=(0.0, 10000.0),
        doc=('\n'
             'Smallest std (m) ever trusted, whatever the covariance says: '
             'firmware that reports a\n'
             'zero covariance would otherwise freeze the filter on that fix. '
             'Lower it only for RTK.')),
    'motion_model': Param(
        'fit',
        ("fit: each collar's motion model (an integrated Ornstein-Uhlenbeck "
         'velocity) and fix std refitted by maximum likelihood as its fixes '
         'arrive, the walk of walk_accel_std and velocity_tau its prior and walk '
         'component; fixed: the model of accel_std and velocity_tau for every '
         'collar'),
        choices=('fit', 'fixed'),
        doc=('\n'
             "fit: each collar's motion model (an integrated Ornstein-Uhlenbeck "
             'velocity: random\n'
             'walk ... constant velocity, as crawl and ctmm) and the std of its '
             'fixes without a\n'
             'covariance are refitted by maximum likelihood of its Kalman '
             'innovations after its\n'
             '20th, 40th, 80th, ... fix (then every 1000), on its last '
             'motion_window accepted\n'
             'fixes; the walk of walk_accel_std / velocity_tau below is the '
             'broad component of a\n'
             'graze/walk mixture and the prior until the first fit. fixed: '
             'accel_std / velocity_tau\n'
             'for every collar (the pre-fit behaviour). `herd-ros ingest` runs '
             'the same schedule,\n'
             'so a file and the live graph give the same track.')),
    'motion_window': Param(
        200,
        'accepted fixes per collar its motion model is fitted on',
        range=(20, 100000)),
    'refit_lag_s': Param(
        -1.0,
        ("data time (s) from a collar's motion refit to the first fix its new model "
         'filters; -1 = 6 ms per collar of agents'),
        range=(-1.0, 86400.0),
        doc=('\n'
             "Data time (s) from a collar's motion refit (motion_model fit) to the "
             'first fix its\n'
             'new model filters; -1: 6 ms per collar of agents (0.1 s for 19 collars, '
             '60 s for\n'
             '10 000). The refits run in the background meanwhile; a fix that needs a '
             'model not\n'
             'yet fitted waits for it, so keep it longer than a refit of every collar '
             'takes.\n'
             '`herd-ros ingest --refit-lag` must match it for a file to give the live '
             'track.')),
    'walk_probability': Param(
        0.05,
        ('prior probability per fix that a fitted collar walks (moves by the '
         'broad model of accel_std and velocity_tau)'),
        range=(1e-06, 0.999999),
        doc=('Prior probability per fix that a fitted collar walks (moves by '
             'the broad model).')),
    'accel_std': Param(
        0.05,
        ('std of the white-noise acceleration (m/s²) of the motion model of '
         'motion_model fixed'),
        range=(0.0, 100.0),
        live=True,
        doc=('\n'
             'Std of the white-noise acceleration (m/s^2) of the motion model of '
             'motion_model fixed\n'
             '(every collar\'s). Grazing cattle move at 0.05-0.3 m/s and walk at '
             '~1 m/s, changing\n'
             'speed over tens of seconds: 0.05 m/s^2 lets the velocity drift ~0.4 '
             'm/s in a minute.\n'
             'With velocity_tau 120 the stationary speed std is accel_std * '
             'sqrt(velocity_tau / 2)\n'
             '= 0.39 m/s per axis. Raise it (0.2-0.5) for animals that are '
             'chased.')),
    'walk_accel_std': Param(
        0.1,
        ('std of the white-noise acceleration (m/s²) of the walk component and '
         'the prior of motion_model fit'),
        range=(1e-06, 100.0),
        live=True,
        doc=('\n'
             'Std of the white-noise acceleration (m/s^2) of the walk (motion_model '
             'fit): the broad\n'
             'component of each collar\'s graze/walk mixture, and its prior until '
             'the first fit. A\n'
             'walking animal: with velocity_tau 120 the stationary speed std is '
             '0.1 * sqrt(60) =\n'
             '0.77 m/s per axis, 1.1 m/s in the plane (cattle walk to water at ~1 '
             'm/s). The grazing\n'
             'and resting animal is the collar\'s own fitted model.')),
    'velocity_tau': Param(
        120.0,
        ('velocity correlation time (s) of the motion model; 0 = constant '
         'velocity'),
        range=(0.0, 1000000.0),
        doc=('\n'
             'Velocity correlation time (s) of the motion model: a '
             'continuous-time correlated\n'
             'random walk (Johnson et al. 2008, the model of crawl/aniMotum), '
             'whose velocity\n'
             'forgets itself after about this long. 0 = constant velocity (the '
             'classic tracking\n'
             'model). Keep it > 0 for duty-cycled collars (a fix every 30 s to '
             '5 min): a\n'
             'constant-velocity filter turns a displacement over minutes into a '
             'velocity it then\n'
             'extrapolates, by kilometres on real collars. At 1 Hz both models '
             'agree.')),
    'gate_probability': Param(
        0.999,
        'probability inside the Mahalanobis gate (χ², 2 dof)',
        range=(0.5, 1.0),
        doc=('\n'
             'Probability inside the Mahalanobis gate (chi-square, 2 dof): '
             '0.999 rejects 1 good fix\n'
             'in 1000 and any fix more than ~3.7 sigma from the prediction.')),
    'max_speed': Param(
        3.0,
        ('fastest speed (m/s) an animal keeps up for sprint_s: the reach beyond '
         'which a fix is an outlier'),
        range=(0.0, 1000.0),
        live=True,
        doc=('\n'
             'Speed envelope: a fix farther from the last estimate than\n'
             '  max_speed * min(elapsed, sprint_s) + cruise_speed * (elapsed - '
             'sprint_s) + gate * sigma\n'
             'is beyond reach (an outlier, not an animal). max_speed (m/s) is '
             "the paper's 3 m/s\n"
             'gate (Schwager et al. 2007), a short burst; cruise_speed (m/s) '
             'the fastest speed an\n'
             'animal keeps up for minutes (cattle walk to water at ~1 m/s, '
             'baboons travel at\n'
             '0.5-1 m/s); sprint_s how long max_speed lasts: d(250 s) = 370 m, '
             'an average of\n'
             '1.5 m/s. With 1 Hz collars only max_speed matters; with fixes '
             'minutes apart\n'
             'the envelope stops outliers a few hundred metres off from passing '
             'because the\n'
             'interval was long.')),
    'cruise_speed': Param(
        1.0,
        'fastest speed (m/s) kept up for minutes (reach after sprint_s)',
        range=(0.0, 1000.0),
        live=True),
    'sprint_s': Param(
        60.0,
        'how long (s) max_speed lasts in the reach envelope',
        range=(0.0, 1000000.0),
        live=True),
    'stale_after': Param(
        30.0,
        ('s of data time without an accepted fix after which a collar is stale '
         '(NaN in /herd/poses)'),
        range=(0.001, 1000000000.0),
        doc=('\n'
             'A collar without an accepted fix for longer (s of data time) is '
             'stale: its pose in\n'
             '/herd/poses is NaN (missing, never an extrapolation), '
             '/herd/<agent>/odom stops until\n'
             'it reports again, diagnostics say WARN, and the herd clock stops '
             'waiting for it.\n'
             'About three fix intervals: 30 s for 1 Hz collars, 3 x the longest '
             'usual interval for\n'
             'duty-cycled ones (herd-ros derives it from the data: 3 x the 90th '
             'percentile).')),
    'initial_velocity_std': Param(
        0.0,
        'velocity std (m/s) when a filter (re)starts; 0 = max_speed',
        range=(0.0, 1000.0),
        doc=('\n'
             'Velocity std (m/s) when a filter (re)initialises; 0 = max_speed.')),
    'confirm_fixes': Param(
        2,
        'consistent fixes that replace a track whose animal walked off',
        range=(1, 1000),
        doc=('\n'
             'Rejected fixes are kept as candidate tracks (chains of mutually '
             'consistent fixes).\n'
             'A candidate whose first fix was within reach (it failed only the '
             'Mahalanobis gate:\n'
             'an animal that walked off) replaces the track after confirm_fixes '
             'fixes; one that\n'
             'began beyond reach (a GPS outlier burst, typically 3-10 fixes '
             'hundreds of metres to\n'
             'kilometres off) only after reacquire_fixes fixes, so bursts never '
             'move the track\n'
             'while a track that really is wrong is still left in the end.')),
    'reacquire_fixes': Param(
        12,
        ('consistent fixes that replace a track from beyond reach (outlier '
         'bursts never reach it)'),
        range=(1, 10000)),
    'range_sigmas': Param(
        6.0,
        ('a candidate this many σ outside the collar\'s range needs reacquire_fixes '
         '(0 = off)'),
        range=(0.0, 1000.0),
        doc=('\n'
             'Each collar keeps the range of its accepted states (running mean and '
             'covariance).\n'
             'A fix farther than range_sigmas (Mahalanobis) and range_margin metres '
             'beyond 3 σ\n'
             'of it, once the collar has range_min_fixes states, starts a candidate '
             'that needs\n'
             'reacquire_fixes, as a jump: over minutes a burst a few hundred metres '
             'off is\n'
             '"within reach", not within the animal\'s range.')),
    'range_margin': Param(
        200.0,
        'metres beyond 3 σ of the range a fix must also be to count as far outside it',
        range=(0.0, 1000000.0)),
    'range_min_fixes': Param(
        30,
        'accepted states a collar needs before its range is used',
        range=(1, 1000000)),
    'confirm_fixes_lost': Param(
        2,
        'consistent fixes that start a new track',
        range=(1, 1000),
        doc=('\n'
             'A new track (first fixes of a collar, or after a silence longer '
             'than\n'
             'reinit_after_gap s) starts only on confirm_fixes_lost mutually '
             'consistent fixes: a\n'
             'lone outlier never becomes the track.')),
    'reinit_after_gap': Param(
        300.0,
        'a silence longer than this (s) restarts the track',
        range=(0.0, 1000000000.0)),
    'frame_id': Param(
        'map',
        'frame of /herd/<agent>/odom and /herd/poses',
        doc=('\n'
             'Frame of /herd/<agent>/odom and /herd/poses (child frame of odom: '
             '<agent>).')),
    'diagnostics_period_s': Param(
        1.0,
        'period (s, wall time) of /diagnostics',
        range=(0.001, 3600.0),
        doc=('\n'
             'Wall-clock period (s) of /diagnostics.')),
    'diagnostics_max_collars': Param(
        1000,
        ('collar statuses per diagnostics period; more collars are reported in '
         'turn'),
        range=(1, 10000000),
        doc=('\n'
             'At most this many collar statuses per diagnostics period (50 per '
             'DiagnosticArray);\n'
             'a larger herd is reported in turn (10 000 collars: each every 10 '
             "periods). The node's\n"
             'own status (totals: fixes, accepted, stale collars) comes every '
             'period.')),
    'batch_period_s': Param(
        0.005,
        ('fixes are filtered in batches every this many s (wall time); 0 = each '
         'fix as it arrives'),
        range=(0.0, 1.0),
        doc=('\n'
             'Fixes are queued serialized by the subscription callbacks, then '
             'decoded and filtered\n'
             'in batches every this many seconds of wall time (all collars at '
             'once, compiled); 0 =\n'
             'each fix as it arrives. 5 ms keeps fix -> odom latency low and '
             'the per-fix cost small.\n'
             'With the batches, the motion refits (`motion_model` fit) run in a '
             'worker thread and\n'
             'a fix waits only for a new model it needs (refit_lag_s) that is not '
             'fitted yet; with 0\n'
             'they run in line.')),
    'max_stamp_ahead_s': Param(
        600.0,
        'a fix stamped more than this (s) ahead of the wall clock is rejected',
        range=(0.001, 1000000000000.0),
        doc=('\n'
             'A fix stamped more than this (s) ahead of the wall clock is '
             'rejected (reason\n'
             '`future`): one wrong stamp must not drag the herd clock into the '
             'future.')),
    'silence_grace_s': Param(
        1.0,
        ('a collar counts as silent for the herd clock only after sending nothing for '
         'this long (s, wall time); 0 = data time alone'),
        range=(0.0, 3600.0),
        doc=('\n'
             'The herd clock publishes a tick once every collar has reported at or '
             'after it, or has\n'
             'been silent for more than stale_after of data time. Data time alone '
             'cannot tell a\n'
             'silent collar from one whose fixes are still queued: a busy machine '
             'working off a\n'
             'backlog takes one message per topic in turn, so a collar that reports '
             'every 5 s runs\n'
             'ahead of those that report every second, and every other collar '
             'looked silent (NaN)\n'
             'in every pose. A collar must also have sent nothing for this many '
             'seconds of wall\n'
             'time: one whose fixes are still arriving is waited for.')),
    'max_clock_jump_s': Param(
        3600.0,
        ('a forward jump of data time larger than this (s) restarts the herd '
         'clock'),
        range=(0.001, 1000000000000.0),
        doc=('\n'
             'If the data time jumps forward by more than this (s) — a bag with '
             'two recordings, a\n'
             'collar stamped 0 at boot — the herd clock restarts at the new '
             'time instead of\n'
             'publishing every tick of the gap.')),
    'fix_queue_depth': Param(
        50,
        ('history depth of each /herd/<agent>/fix subscription (of fix_topic: '
         'this times the collars)'),
        range=(1, 100000),
        doc=('\n'
             'History depth of each /herd/<agent>/fix subscription (sensor-data '
             'QoS: best effort,\n'
             "keep last N). 50 instead of the profile's 5: a bag replayed at "
             '10-100x, or a second\n'
             'in which the node is busy, must not overwrite fixes before they '
             'are filtered.')),
    'fix_topic': Param(
        '',
        ('one NavSatFix topic for every collar, the collar named by '
         'header.frame_id (<agent>, <agent>_gps or <agent>/gps); empty = '
         '/herd/<agent>/fix per collar'),
        doc=('\n'
             'Large herds: one NavSatFix topic for every collar (what a LoRa or '
             'satellite gateway\n'
             'publishes), the collar named by header.frame_id (`cow_17`, '
             '`cow_17_gps` or\n'
             '`cow_17/gps`); its history is fix_queue_depth x collars. Empty = '
             'one\n'
             '/herd/<agent>/fix topic per collar. Use it beyond ~1000 collars: '
             'DDS endpoints and\n'
             'their discovery grow faster than the herd (20 000 endpoints took '
             '3 min to build and\n'
             '11 min to discover), while one topic served 10 000 collars at 1 '
             'Hz.')),
    'odom_topic': Param(
        '',
        ('one Odometry topic for every collar (child_frame_id = the collar); '
         'empty = /herd/<agent>/odom per collar'),
        doc=('\n'
             'Likewise one nav_msgs/Odometry topic for every collar '
             '(child_frame_id = the collar,\n'
             'keep last 10 x collars); empty = /herd/<agent>/odom per collar. '
             'Independent of\n'
             'fix_topic.')),
    'executor': Param(
        'events',
        'rclpy executor',
        choices=('events', 'single_threaded'),
        doc=('\n'
             '`events` = rclpy.experimental.EventsExecutor (about 4x the '
             'small-message throughput\n'
             'of the default executor, what 1000 collars need); '
             '`single_threaded` = the classic\n'
             'SingleThreadedExecutor (fallback, also used automatically if '
             '`events` is missing).')),
}

TABLE = NodeTable('gps_ingest', HEADER, PARAMS)

#: The node parameters that are :class:`~herd_ros.ingest.collar_filter.FilterParams` fields
FILTER_FIELDS = ('accel_std', 'velocity_tau', 'default_position_std', 'position_std_floor',
                 'gate_probability', 'max_speed', 'cruise_speed', 'sprint_s', 'stale_after',
                 'initial_velocity_std', 'confirm_fixes', 'reacquire_fixes',
                 'confirm_fixes_lost', 'reinit_after_gap', 'walk_probability',
                 'range_sigmas', 'range_margin', 'range_min_fixes')
#: history depth of each /herd/<agent>/odom publisher (of odom_topic: this times the collars)
ODOM_DEPTH = 10


class GpsIngestConfig:
    """``gps_ingest`` parameters (values checked against :data:`PARAMS`) made into what the
    node runs with; raises :class:`~herd_ros.params.ParameterError` naming what is wrong
    beyond the table's checks."""

    def __init__(self, p: dict):
        from herd_ros.errors import HerdInputError
        from herd_ros.ingest.collar_filter import FilterParams
        from herd_ros.ingest.pipeline import choose_datum, refit_config, with_walk
        from herd_ros.params import ParameterError, distinct_ids, topic_problem
        self.agents = distinct_ids(p, 'agents', 'collar ids')
        try:
            self.datum = choose_datum(None, [float(v) for v in p['datum']]) if len(
                p['datum']) else None
        except (HerdInputError, TypeError, ValueError):
            raise ParameterError(f'datum must be [] (first valid fix), [lat, lon] or [lat, '
                                 f'lon, alt] (finite degrees within ±90/±180, metres), got '
                                 f'{list(p["datum"])!r}') from None
        for name in ('dt', 'diagnostics_period_s', 'max_stamp_ahead_s', 'max_clock_jump_s',
                     'batch_period_s', 'diagnostics_max_collars', 'executor', 'motion_model',
                     'silence_grace_s'):
            setattr(self, name, p[name])
        filt = {name: p[name] for name in FILTER_FIELDS}
        filt['initial_velocity_std'] = filt['initial_velocity_std'] or None
        try:
            self.filter_params = FilterParams(**filt)
        except HerdInputError as exc:
            raise ParameterError(str(exc).replace('filter parameter ', '')) from None
        self.refit = None
        if self.motion_model == 'fit':
            self.filter_params = with_walk(self.filter_params, p['walk_accel_std'])
            self.refit = refit_config(self.filter_params, p['motion_window'],
                                      lag_s=p['refit_lag_s'], collars=len(self.agents))
        self.frame_id = str(p['frame_id']).strip()
        if not self.frame_id:
            raise ParameterError('frame_id must be a non-empty frame name')
        for name in ('fix_topic', 'odom_topic'):
            topic = str(p[name]).strip()
            why = topic and topic_problem(topic)
            if why:
                raise ParameterError(f'{name} must be empty or a topic name, got {topic!r} '
                                     f'({why})')
            setattr(self, name, topic)
        n = len(self.agents)
        self.fix_depth = min(p['fix_queue_depth'] * (n if self.fix_topic else 1), 10**7)
        self.odom_depth = ODOM_DEPTH * (n if self.odom_topic else 1)
