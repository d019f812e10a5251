"""`estimator` node: learns the herd model online from `/herd/poses` (recursive least squares).

Subscribes ``/herd/poses`` (PoseArray, one snapshot per herd-clock tick in ``agents`` order;
a NaN pose = missing, its update skipped). Publishes ``/herd/model/params``
(Float64MultiArray ``agent`` × ``param``, rows θ_i as in doc/formats.md: [damping, theta1..,
theta2.., field_u.., field_v..], shared law [damping, profile.., field_u.., field_v..]) and,
latched, ``/herd/model/structure`` (how to read them: :mod:`herd_ros.model.model_structure`),
``/herd/model/noise`` (Q_i), ``/herd/model/noise_regimes`` (stop-and-go noise refitted
every ``regime_refit_every`` updates, :mod:`herd_ros.estimation.online_regimes`),
``/herd/model/prediction`` (one step ahead, eq. 8, stamped
with the tick it predicts), ``/herd/model/markers`` (:mod:`herd_ros.nodes.model_markers`)
and ``/diagnostics`` (per agent samples, residual RMS, whiteness, condition of P, skill
against the naive baselines; clock problems as WARN). Services ``~/save_model`` and
``~/reset`` (std_srvs/Trigger). Checkpoints of the whole state every
``checkpoint_period_s`` and on shutdown, resumed at start when compatible; data time far
behind them starts a new session (:mod:`herd_ros.estimation.sessions`).

The numerics are :class:`herd_ros.herd_dynamics.HerdDynamics` learning online; this node
only converts messages and parameters.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from herd_ros.errors import HerdInputError
from herd_ros.estimation.online_status import agent_statuses, herd_skill
from herd_ros.estimation.sessions import set_aside
from herd_ros.herd_dynamics import HerdDynamics
from herd_ros.nodes.ros_common import (OK, WARN, LiveParameters, data_path, declare_parameters,
                                       describe_remaining_parameters, diagnostic_array,
                                       diagnostic_status, exit_process, matrix_message,
                                       run_node, seconds_to_stamp, stamp_to_seconds,
                                       tensor_message, wall_timer)
from herd_ros.nodes.model_markers import model_markers, pose_at
from herd_ros.params.estimator import (LEARNER_OPTIONS, PARAMS as DEFAULTS, check,
                                      forgetting_problem)

#: the columns of /herd/model/home and /herd/model/place: each animal's range (mean,
#: covariance) and the gain of the pull at its edge
RANGE_COLUMNS = 'mux_muy_kxx_kxy_kyx_kyy_sxx_sxy_syx_syy'


def read_parameters(node: Node) -> dict:
    """Declare and check every parameter (:func:`~herd_ros.params.estimator.check`);
    relative file names are under the data directory."""
    values = check(declare_parameters(node, DEFAULTS))
    for name in ('model_out', 'checkpoint_path'):
        values[name] = str(data_path(values[name])) if values[name] else ''
    return values


class Estimator(Node):
    """Messages in, :class:`~herd_ros.herd_dynamics.HerdDynamics` learning online in the
    middle, messages out."""

    def __init__(self):
        super().__init__('estimator')
        self.cfg = cfg = read_parameters(self)
        self.dynamics = HerdDynamics.online_learner(cfg['agents'], cfg['dt'], **{
            k: cfg[k] for k in LEARNER_OPTIONS})
        self.core = self.dynamics.online         # checkpoints, statistics, markers
        self.counts = dict(snapshots=0, updates=0, gaps=0, backwards=0, between=0,
                           sessions=1, regime_fits=0)
        self.regimes_said = None          # the regime count last logged
        self._regime_pool, self._regime_job, self._regime_generation = None, None, 0
        self.clock_warning = ''
        self._resume()
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.create_publisher(String, '/herd/model/structure', latched).publish(
            String(data=self.core.structure().to_json()))
        self.params_pub = self.create_publisher(Float64MultiArray, '/herd/model/params', 10)
        self.noise_pub = self.create_publisher(Float64MultiArray, '/herd/model/noise', 10)
        self.home_pub = self.create_publisher(Float64MultiArray, '/herd/model/home', 10)
        self.place_pub = self.create_publisher(Float64MultiArray, '/herd/model/place', 10)
        self.regimes_pub = self.create_publisher(Float64MultiArray,
                                                 '/herd/model/noise_regimes', latched)
        self.pred_pub = self.create_publisher(PoseArray, '/herd/model/prediction', 10)
        self.marker_pub = self.create_publisher(MarkerArray, '/herd/model/markers', 1)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(PoseArray, '/herd/poses', self.on_poses, qos)
        self.create_service(Trigger, '~/save_model', self.on_save_model)
        self.create_service(Trigger, '~/reset', self.on_reset)
        wall_timer(self, cfg['diagnostics_period_s'], self.publish_status)
        if cfg['checkpoint_path']:
            wall_timer(self, cfg['checkpoint_period_s'], self.write_checkpoint)
        describe_remaining_parameters(self, 'not an estimator parameter (ignored)')
        LiveParameters(self, self._validate_live, self._apply_live)
        self.get_logger().info(
            f'{len(cfg["agents"])} agents, dt {cfg["dt"]:g} s, law {cfg["law"]}, '
            f'{self.core.regressor.n_params} parameters per agent; model file '
            f'{cfg["model_out"] or "(none)"}, checkpoints '
            f'{cfg["checkpoint_path"] or "(none)"} every {cfg["checkpoint_period_s"]:g} s')

    # -- live parameters (forgetting, robust, model_out) -----------------------------------
    def _validate_live(self, name, value):     # types: checked against the table
        if name == 'forgetting':
            return forgetting_problem(value)
        return 'must be a file name' if name == 'model_out' and not value.strip() else None

    def _apply_live(self, name, value):
        if name == 'forgetting':
            self.core.rls.forgetting = float(value)     # read at every update
        elif name == 'robust':
            self.core.robust = bool(value)
        elif name == 'model_out':
            value = str(data_path(value))
        self.cfg[name] = value

    # -- start and stop --------------------------------------------------------------------
    def _resume(self):
        try:
            if not (path := self.cfg['checkpoint_path']):
                return
            if self.core.load_checkpoint(path):
                self.get_logger().info(f'resumed from checkpoint {path}: '
                                       f'{self.core.describe_session()}')
            else:
                self.get_logger().info(f'no checkpoint at {path}: starting afresh')
        except HerdInputError as exc:
            self.get_logger().warning(f'{exc}; starting afresh (it will be overwritten)')

    def write_checkpoint(self):
        """Save the estimator's state (a failure is logged; learning goes on)."""
        try:
            self.core.save_checkpoint(self.cfg['checkpoint_path'])
        except OSError as exc:   # a full disk must not stop the learning
            self.get_logger().error(f'cannot write checkpoint: {exc}')

    def on_shutdown(self):
        """On a stop signal: the checkpoint, and the model learned so far (``model_out``),
        so nothing learned is lost however the node is stopped (short of ``kill -9``)."""
        if self._regime_pool is not None:
            self._regime_pool.shutdown(wait=False, cancel_futures=True)
        if self.cfg['checkpoint_path']:
            self.write_checkpoint()
        if self.cfg['model_out'] and self.counts['updates'] > 0:
            try:
                path = self.core.save_model(self.cfg['model_out'],
                                            frame_id=self.cfg['frame_id'])
                print(f'estimator: model written to {path}', file=sys.stderr)
            except (HerdInputError, OSError) as exc:
                print(f'estimator: model not written: {exc}', file=sys.stderr)

    # -- data ------------------------------------------------------------------------------
    def on_poses(self, msg: PoseArray):
        """Learn from a /herd/poses snapshot and publish what changed."""
        n = len(self.core.agents)
        if len(msg.poses) != n:
            self._warn(f'/herd/poses has {len(msg.poses)} poses, expected {n} (agents): ignored')
            return
        t = stamp_to_seconds(msg.header.stamp)
        positions = np.array([[p.position.x, p.position.y] for p in msg.poses])
        result = self.dynamics.partial_fit(t, positions)
        self.counts['snapshots'] += 1
        if result.status == 'backwards' and -result.step > self.cfg['new_session_after_s']:
            self._new_session(t, -result.step)
            result = self.dynamics.partial_fit(t, positions)
        if result.status == 'backwards':
            self.counts['backwards'] += 1
            self._warn(f'snapshot at {t:.3f} s is not after the previous one: ignored')
            return
        if result.status == 'between':
            self.counts['between'] += 1          # a finer herd clock: skipped, as it should
            self.take_regimes()
            return                               # (its prediction is already out)
        if result.status == 'gap':
            self.counts['gaps'] += 1
            self._warn(f'snapshot step {result.step:.3f} s differs from dt {self.core.dt:g} s: '
                       f'the pair is not used')
        self.take_regimes()
        if result.status == 'updated':
            self.counts['updates'] += 1
            self.publish_params(msg.header.stamp)
            if (self.cfg['regime_window'] > 0
                    and self.counts['updates'] % self.cfg['regime_refit_every'] == 0):
                self.refit_regimes()
        self.publish_prediction()

    def refit_regimes(self):
        """Start a refit of the stop-and-go noise on a copy of the residual window in the
        worker thread (one at a time: a refit still running skips this turn); a later
        snapshot publishes it (:meth:`take_regimes`), so a large herd's refit (1 000 agents:
        2-3 s) never holds up the snapshots."""
        if self._regime_job is not None:
            return
        residuals = self.core.regime_residuals()
        if residuals is None:
            return
        from concurrent.futures import ThreadPoolExecutor

        from herd_ros.estimation.online_regimes import fit_residuals
        if self._regime_pool is None:
            self._regime_pool = ThreadPoolExecutor(max_workers=1,
                                                   thread_name_prefix='noise_regimes')
        self._regime_job = (self._regime_generation,
                            self._regime_pool.submit(fit_residuals, residuals),
                            self.counts['updates'] + self.cfg['regime_adopt_after'])

    def take_regimes(self):
        """Adopt and publish a refit at its update (``regime_adopt_after`` after it started,
        waiting for it there: data time, so a replay gives the same regimes at the same
        snapshot at any rate); K = 1, plain Gaussian noise, is published too (a controller
        drops earlier regimes); one fitted before a reset is dropped."""
        job = self._regime_job
        if job is None or self.counts['updates'] < job[2]:
            return
        self._regime_job = None
        generation, future, _ = job
        if generation != self._regime_generation:
            return
        try:
            fit = self.core.adopt_regimes(future.result())
        except Exception as exc:  # noqa: BLE001 - a failed refit must not stop the learning
            self.get_logger().error(f'noise regimes: refit failed ({exc}); keeping the last')
            return
        if fit is None:
            return
        from herd_ros.estimation.online_regimes import pack_regimes
        self.counts['regime_fits'] += 1
        k = fit['n_regimes']
        self.regimes_pub.publish(tensor_message(pack_regimes(*self.core.published_regimes()),
                                                ('agent', 'regime', 'q4_transition')))
        if k != self.regimes_said:
            self.regimes_said = k
            bic = fit['bic']
            self.get_logger().info(
                f'noise regimes: {k} by BIC on the last {self.core.residual_window.filled} '
                f'steps' + ('' if k > 1 else ' (Gaussian noise)') + ' (BIC ' + ', '.join(
                    f'{j}: {bic[j] - bic[1]:+.0f}' for j in sorted(bic)) + ')')

    def _forget_regimes(self):
        """A reset or a new session: a refit under way is dropped when it ends."""
        self._regime_generation += 1
        self._regime_job = None
        self.regimes_said = None

    def _new_session(self, t: float, back: float):
        """Data time went back by more than ``new_session_after_s``: a new session (a resume
        after a crash continues the data, so it never lands here)."""
        self.cfg['checkpoint_path'] and self.write_checkpoint()   # the old session, as learned
        aside, learned = set_aside(self.cfg['checkpoint_path']), self.core.describe_session()
        self.core.reset()
        self.counts['sessions'] += 1
        self._forget_regimes()
        self.get_logger().info(
            f'data time went back {back:.0f} s (to {t:.3f}): a new session, learning afresh'
            + (f'; the previous one ({learned}) is kept as {aside}' if aside else ''))

    def _warn(self, text: str):
        self.clock_warning = text
        self.get_logger().warning(text, throttle_duration_sec=5.0)
        self.diag_pub.publish(diagnostic_array(self, [diagnostic_status(
            'estimator: herd clock', WARN, text, dict(self.counts))]))

    def publish_params(self, stamp=None):
        """Publish the law of the model file: θ, Q, each animal's range and home pull and
        its place in the herd (agent × param, agent × 4, agent × 10, agent × 10)."""
        theta, home, place = self.core.published_law()
        n = len(theta)
        self.params_pub.publish(matrix_message(theta, 'param'))
        self.noise_pub.publish(matrix_message(
            self.core.rls.noise_cov().reshape(n, 4), 'qxx_qxy_qyx_qyy'))
        for pub, (mean, gain, cov) in ((self.home_pub, home), (self.place_pub, place)):
            pub.publish(matrix_message(np.hstack([mean, gain.reshape(n, 4),
                                                  cov.reshape(n, 4)]), RANGE_COLUMNS))

    def publish_prediction(self):
        """Publish the one-step prediction of the next tick."""
        pred = self.core.predict()
        if pred is None:
            return
        t, positions = pred
        msg = PoseArray()
        msg.header.stamp = seconds_to_stamp(t)
        msg.header.frame_id = self.cfg['frame_id']
        msg.poses = [pose_at(x, y) for x, y in positions]
        self.pred_pub.publish(msg)
        self._last_prediction = positions

    # -- status ----------------------------------------------------------------------------
    def publish_status(self):
        """Publish the herd clock's and each agent's status on /diagnostics."""
        statuses = [diagnostic_status(
            'estimator: herd clock', WARN if self.clock_warning else OK,
            self.clock_warning or 'snapshots on the clock', dict(self.counts)),
            diagnostic_status('estimator: prediction skill', OK,
                              'running one-step RMS (m) of the herd: model (predicted before '
                              'each update) vs constant velocity vs stay-put',
                              herd_skill(self.core))]
        for agent, warn, message, values in agent_statuses(self.core):
            statuses.append(diagnostic_status(f'estimator: {agent}', WARN if warn else OK,
                                              message, values, hardware_id=agent))
        self.clock_warning = ''
        self.diag_pub.publish(diagnostic_array(self, statuses))
        self.publish_markers()

    def publish_markers(self):
        """Publish the field, centres and prediction as markers."""
        self.marker_pub.publish(model_markers(self.core, self.cfg['frame_id'],
                                              getattr(self, '_last_prediction', None)))

    # -- services --------------------------------------------------------------------------
    def on_save_model(self, request, response):
        """Service ~/save_model: write the model file; the response names it."""
        try:
            path = self.core.save_model(self.cfg['model_out'], frame_id=self.cfg['frame_id'])
            response.success, response.message = True, str(Path(path).resolve())
        except (HerdInputError, OSError) as exc:
            response.success, response.message = False, str(exc)
        return response

    def on_reset(self, request, response):
        """Service ~/reset: θ and P back to their start, counters zero."""
        self.core.reset()
        self._forget_regimes()
        self.get_logger().info('estimator reset: θ = θ₀, P = P₀, counters zero')
        response.success, response.message = True, 'reset'
        return response


def main(args=None):
    """Run the node (``ros2 run herd_ros NODE``); exits with its status."""
    exit_process(run_node(Estimator, args=args))


if __name__ == '__main__':
    raise SystemExit(main())
