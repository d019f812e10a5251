"""Parameters of the ``estimator`` node: the one table its ROS parameters, their checks,
``config/estimator.yaml`` and the documentation come from (:mod:`herd_ros.params`)."""
from herd_ros.params import NodeTable, Param

HEADER = ('# estimator: learns the herd model online (recursive least squares) from '
          '/herd/poses.\n'
          '# Run: ros2 run herd_ros estimator --ros-args --params-file '
          'config/estimator.yaml\n')

PARAMS = {
    'agents': Param(
        [],
        'agent ids in the order of the poses in /herd/poses (required)',
        example=['cow_1', 'cow_2', 'cow_3'],
        doc=('Agent ids in the order of the poses in /herd/poses (same list as '
             'gps_ingest). Required.')),
    'dt': Param(
        0.0,
        ('model step (s): snapshots one step apart are paired; closer ones are '
         'skipped, further ones not paired (required, > 0)'),
        example=1.0,
        doc=("Model step (s): the law is learned from snapshots this far apart. "
             'A herd clock finer\n'
             'than it (gps_ingest at 1 s for a fresh /herd/poses, the law at the '
             "collars' 2-minute\n"
             'interval) is fine when its step divides dt: the snapshots in between '
             'are skipped\n'
             "(counted 'between'). A step longer than dt by more than 0.1 % is "
             'reported (WARN) and\n'
             'that pair is not used. Required.')),
    'law': Param(
        'pairwise',
        ('interaction law: pairwise (the paper) or shared (one distance '
         'profile, neighbours within interaction_radius)'),
        choices=('pairwise', 'shared'),
        doc=('Interaction law: pairwise (the paper: theta1/theta2 per '
             'neighbour, cost grows with N²;\n'
             'fine up to a few dozen animals) or shared (one distance profile '
             'per animal, neighbours\n'
             'within interaction_radius; use for hundreds to thousands of '
             'animals).')),
    'forgetting': Param(
        1.0,
        'RLS forgetting factor λ in (0, 1]; 1 = never forget',
        range=(0.0, 1.0),
        live=True,
        doc=('RLS forgetting factor λ in (0, 1]. 1 = never forget (equals batch '
             'least squares).\n'
             'With directional forgetting the memory is roughly p/(2(1 − λ)) '
             'samples for p parameters;\n'
             "lower it (e.g. 0.95–0.99) when the herd's behaviour changes with "
             'season or paddock.')),
    'p0': Param(
        1000000.0,
        'initial covariance P0 = p0·I (units of the noise variance)',
        range=(1e-12, 1e+300),
        doc=('Initial covariance P0 = p0·I, in units of the noise variance: the '
             'ridge prior θ ~ N(0, p0 σ²).\n'
             'Large (1e6) = uninformative; smaller keeps rarely visited field '
             'centres near zero.')),
    'field_grid': Param(
        [6, 6],
        'RBF field grid [nx, ny] over field_bounds',
        doc=('RBF field grid [nx, ny] over field_bounds. Online the centres are '
             'fixed: all grid\n'
             'centres are estimated; the saved model keeps only cells an agent '
             'visited min_visits times.')),
    'field_bounds': Param(
        [-75.0, 75.0, -75.0, 75.0],
        'field bounds [xmin, xmax, ymin, ymax] (m, frame_id)',
        doc=('Field bounds [xmin, xmax, ymin, ymax] in metres (frame map). '
             'Cover the paddock.')),
    'min_visits': Param(
        10,
        ('samples an agent needs in a cell for its centre to be kept in the '
         'saved model'),
        range=(0, 1000000),
        doc=('Samples an agent needs in a cell for its centre to be kept in the '
             'saved model.')),
    'range_pulls': Param(
        True,
        ('publish each animal\'s range and place in the herd with the pulls at their '
         'edges, and save them in the model'),
        doc=('Publish each animal\'s range and its place in the herd with the pulls at '
             'their edges\n'
             '(/herd/model/home, /herd/model/place: robots stay in their animals\' ranges '
             'and places)\n'
             'and save them in the model file; false = the learned law alone (zero gains '
             'published).')),
    'interaction_radius': Param(
        60.0,
        'shared law: neighbours within this distance (m) interact',
        range=(1e-06, 1000000000.0),
        doc='Shared law only: neighbours within this distance (m) interact.'),
    'profile_size': Param(
        6,
        'shared law: radial basis terms of the distance profile',
        range=(1, 1000),
        doc=('Shared law only: number of radial basis terms of the distance '
             'profile F(d).')),
    'alignment': Param(
        False,
        ('learn a velocity alignment too: each animal matches its neighbours\' '
         'velocity with a distance kernel (its weights: the last columns of θ)'),
        doc=('Learn a velocity alignment too (herd_ros.model.alignment): each '
             'animal\'s acceleration gains\n'
             'the mean of its neighbours\' velocity differences weighted by a '
             'learned kernel of the\n'
             'distance; its alignment_size weights are the last columns of θ.')),
    'alignment_radius': Param(
        40.0,
        'alignment: neighbours within this distance (m) count',
        range=(1e-06, 1000000000.0),
        doc='Alignment only: neighbours within this distance (m) count.'),
    'alignment_size': Param(
        4,
        'alignment: radial basis terms of the kernel',
        range=(1, 100),
        doc='Alignment only: number of radial basis terms of the kernel K(d).'),
    'alignment_neighbourhood': Param(
        'radius',
        'alignment: every neighbour within the radius, or the nearest ones within it',
        choices=('radius', 'nearest'),
        doc=('Alignment only: radius = every neighbour within alignment_radius; '
             'nearest = the\n'
             'alignment_nearest closest within it.')),
    'alignment_nearest': Param(
        7,
        'alignment: how many nearest neighbours (with alignment_neighbourhood nearest)',
        range=(1, 1000),
        doc='Alignment only: k of alignment_neighbourhood nearest.'),
    'robust': Param(
        False,
        ('outlier-robust updates (Chang 2014): an innovation beyond χ²₂(0.95) '
         'gets its noise inflated'),
        live=True,
        doc=('Outlier-robust updates (Chang 2014): an update whose innovation '
             'is beyond χ²₂(0.95)\n'
             'gets its noise inflated until it is not; a burst of bad positions '
             'cannot drag θ.\n'
             'Off by default: on clean real herds it costs ~0.6 % of one-step '
             'RMS (their heavy\n'
             'tails are real movement).')),
    'regime_window': Param(
        240,
        ('steps of standardized one-step residuals kept to fit stop-and-go noise '
         'regimes (published on /herd/model/noise_regimes); 0 = none'),
        range=(0, 1000000),
        doc=('Stop-and-go noise: the last regime_window steps of each agent\'s '
             'standardized one-step\n'
             'residuals are kept, and every regime_refit_every updates the noise '
             'is refitted as a\n'
             'Markov-switching mixture (1-3 regimes by BIC, '
             'herd_ros/model/noise_regimes.py) and\n'
             'published on /herd/model/noise_regimes: robots driven by the live '
             'law rest and move in\n'
             'bursts as the animals do, at the pace of the last window (240 '
             'steps: 20 min at dt 5 s).\n'
             '0 = Gaussian noise (Q_i of the whole run) only; otherwise at least 120.')),
    'regime_refit_every': Param(
        60,
        'updates between refits of the noise regimes',
        range=(1, 1000000000),
        doc=('Updates between refits of the noise regimes (a refit of 19 agents '
             'over 240 steps\n'
             'takes about 0.1 s); the first comes after as many updates.')),
    'regime_adopt_after': Param(
        5,
        'updates from a noise-regime refit to its adoption (data time: repeatable runs)',
        range=(1, 1000000000),
        doc=('A refit of the noise regimes runs in a worker thread and is adopted '
             'and published\n'
             'exactly regime_adopt_after updates after it started, waiting for it '
             'there if it has\n'
             'not finished (a herd of 1 000: 2-3 s), so that a bag replayed at any '
             'rate gives the\n'
             'same regimes at the same snapshot (adopted when the worker finished, '
             'a replay\'s robots\n'
             'drew their noise from another tick from run to run).')),
    'model_out': Param(
        'herd_model.yaml',
        ('model file written by ~/save_model and at stop; relative to the data '
         'directory'),
        live=True,
        doc=('Model file written by the ~/save_model service and when the node '
             'is stopped (ROS\n'
             'parameters YAML of doc/formats.md). Relative paths here and in '
             'checkpoint_path are under\n'
             'the data directory $ROS_HOME/herd_ros (~/.ros/herd_ros), never '
             'the working directory.')),
    'checkpoint_path': Param(
        '',
        ('checkpoint (.npz) of the whole estimator, resumed at start when it '
         'matches; relative to the data directory; empty = none'),
        example='estimator_checkpoint.npz',
        doc=("Checkpoint file (.npz) of the whole estimator state; '' = no "
             'checkpoints. On start the\n'
             'node resumes from it when it exists and matches agents, law, dt '
             'and grid (and logs\n'
             'which); it is also written when the node is stopped.')),
    'checkpoint_period_s': Param(
        60.0,
        's (wall) between checkpoints',
        range=(0.001, 1000000000.0),
        doc=('Seconds between checkpoints (wall time): a kill -9 loses at most '
             'this much learning.')),
    'new_session_after_s': Param(
        60.0,
        ('a snapshot this many s of data time before the latest one starts a '
         'new session (a replay started over): the checkpoint is set aside, the '
         'estimator starts afresh'),
        range=(0.001, 1000000000000.0),
        doc=('A snapshot this many seconds of data time before the latest one '
             'starts a new session\n'
             '(the same bag launched again, a looping replay): the checkpoint '
             'is set aside as\n'
             '<name>.session-<k>.npz and the estimator learns afresh, saying so '
             'in one line.')),
    'diagnostics_period_s': Param(
        1.0,
        's (wall) between /diagnostics and markers',
        range=(0.001, 3600.0),
        doc=('Seconds between /diagnostics and /herd/model/markers messages '
             '(wall time).')),
    'frame_id': Param(
        'map',
        'frame of the predictions and markers',
        doc='Frame of the predictions and markers (REP-105 local ENU frame).'),
}

TABLE = NodeTable('estimator', HEADER, PARAMS)
#: the parameters that are options of the online learner
#: (:meth:`herd_ros.herd_dynamics.HerdDynamics.online_learner`)
LEARNER_OPTIONS = ('law', 'field_grid', 'field_bounds', 'forgetting', 'p0', 'min_visits',
                   'interaction_radius', 'profile_size', 'robust', 'alignment',
                   'alignment_radius', 'alignment_size', 'alignment_neighbourhood',
                   'alignment_nearest', 'regime_window', 'range_pulls')


def check(values: dict) -> dict:
    """The estimator's parameters (checked against :data:`PARAMS`) checked for what the
    table cannot say; :class:`~herd_ros.params.ParameterError` names the one at fault."""
    import math

    from herd_ros.params import ParameterError
    agents = values['agents']
    if not agents or len(set(agents)) != len(agents):
        raise ParameterError('parameter agents must be a non-empty list of distinct agent ids '
                             '(the order of the poses in /herd/poses)')
    if not (math.isfinite(values['dt']) and values['dt'] > 0):
        raise ParameterError(f'parameter dt must be the herd clock step in seconds (> 0), got '
                             f'{values["dt"]}')
    if values['law'] == 'pairwise' and len(agents) < 2:
        raise ParameterError('law pairwise needs at least two agents')
    reason = forgetting_problem(values['forgetting'])
    if reason:
        raise ParameterError(f'parameter forgetting {reason}')
    grid = list(values['field_grid'])
    if len(grid) != 2 or min(grid) < 1:
        raise ParameterError(f'parameter field_grid must be [nx, ny] with nx, ny ≥ 1, got {grid}')
    b = [float(v) for v in values['field_bounds']]
    if len(b) != 4 or not (b[0] < b[1] and b[2] < b[3]):
        raise ParameterError(f'parameter field_bounds must be [xmin, xmax, ymin, ymax] with '
                             f'xmin < xmax and ymin < ymax, got {b}')
    if not values['new_session_after_s'] > 0:
        raise ParameterError(f'parameter new_session_after_s must be positive, got '
                             f'{values["new_session_after_s"]}')
    from herd_ros.estimation.online_regimes import MIN_RESIDUALS
    if 0 < values['regime_window'] < MIN_RESIDUALS:
        raise ParameterError(f'parameter regime_window must be 0 (no noise regimes) or at '
                             f'least {MIN_RESIDUALS} steps (what a first regime fit needs), '
                             f'got {values["regime_window"]}')
    values['field_grid'], values['field_bounds'] = grid, b
    return values


def forgetting_problem(value) -> str | None:
    """Why ``value`` is not a forgetting factor in (0, 1], or None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f'must be a number in (0, 1], got {value!r}'
    if not 0 < value <= 1:
        return f'must be in (0, 1], got {value}'
    return None
