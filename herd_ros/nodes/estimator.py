"""`estimator` node: learns the herd model online from `/herd/poses` (recursive least squares).

Subscribes:
    /herd/poses (geometry_msgs/PoseArray): one snapshot per herd-clock tick, poses in the
        order of ``agents``, header stamp = the tick; a pose with NaN position = agent
        missing or stale in that snapshot (its update is skipped).
Publishes:
    /herd/model/params (std_msgs/Float64MultiArray): θ, dims ``agent`` × ``param``, each row
        θ_i in the order of DESIGN.md ([damping, theta1.., theta2.., field_u.., field_v..];
        shared law: [damping, profile.., field_u.., field_v..]).
    /herd/model/prediction (geometry_msgs/PoseArray): one-step-ahead positions (eq. 8),
        stamped with the tick they predict.
    /herd/model/markers (visualization_msgs/MarkerArray, frame ``map``): field arrows at
        the centres (mean over agents), the centres, the predictions.
    /diagnostics: per agent samples, residual RMS, lag-1 whiteness, condition of P; clock
        problems (a step ≠ dt, time going backwards) as WARN.
Services (std_srvs/Trigger): ~/save_model (writes ``model_out``), ~/reset.
Checkpoints: the whole state to ``checkpoint_path`` (atomic write-then-rename) every
``checkpoint_period_s`` and on shutdown; resumed at start when present and compatible.

The numerics are :class:`herd_ros.estimation.online_fit.OnlineHerdEstimator`; this node only
converts messages and parameters.
"""
from __future__ import annotations

import array
import math
import os
import sys
from pathlib import Path

import numpy as np
from geometry_msgs.msg import Point, Pose, PoseArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import ColorRGBA, Float64MultiArray, MultiArrayDimension
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from diagnostic_msgs.msg import DiagnosticArray
from herd_ros.errors import HerdInputError
from herd_ros.estimation.online_fit import LAWS, OnlineHerdEstimator
from herd_ros.nodes.ros_common import (OK, WARN, LiveParameters, ParameterError,
                                       data_path, declare_parameters,
                                       describe_remaining_parameters, diagnostic_array,
                                       diagnostic_status, exit_process, run_node, seconds_to_stamp,
                                       wall_timer,
                                       stamp_to_seconds)
from herd_ros.params.estimator import PARAMS as DEFAULTS


def read_parameters(node: Node) -> dict:
    """Declare and validate every parameter; ParameterError names the one at fault."""
    values = declare_parameters(node, DEFAULTS)
    agents = values['agents']
    if not agents or len(set(agents)) != len(agents):
        raise ParameterError('parameter agents must be a non-empty list of distinct agent ids '
                             '(the order of the poses in /herd/poses)')
    if values['dt'] is None or not (math.isfinite(values['dt']) and values['dt'] > 0):
        raise ParameterError(f'parameter dt must be the herd clock step in seconds (> 0), got '
                             f'{values["dt"]}')
    if values['law'] not in LAWS:
        raise ParameterError(f'parameter law must be one of {", ".join(LAWS)}, got '
                             f'{values["law"]!r}')
    if values['law'] == 'pairwise' and len(agents) < 2:
        raise ParameterError('law pairwise needs at least two agents')
    reason = _forgetting_problem(values['forgetting'])
    if reason:
        raise ParameterError(f'parameter forgetting {reason}')
    if not (math.isfinite(values['p0']) and values['p0'] > 0):
        raise ParameterError(f'parameter p0 must be a positive number, got {values["p0"]}')
    grid = list(values['field_grid'])
    if len(grid) != 2 or min(grid) < 1:
        raise ParameterError(f'parameter field_grid must be [nx, ny] with nx, ny ≥ 1, got {grid}')
    b = [float(v) for v in values['field_bounds']]
    if len(b) != 4 or not (b[0] < b[1] and b[2] < b[3]):
        raise ParameterError(f'parameter field_bounds must be [xmin, xmax, ymin, ymax] with '
                             f'xmin < xmax and ymin < ymax, got {b}')
    for name in ('checkpoint_period_s', 'diagnostics_period_s', 'interaction_radius',
                 'new_session_after_s'):
        if not values[name] > 0:
            raise ParameterError(f'parameter {name} must be positive, got {values[name]}')
    if values['profile_size'] < 1 or values['min_visits'] < 0:
        raise ParameterError('parameters profile_size must be ≥ 1 and min_visits ≥ 0')
    values['field_grid'], values['field_bounds'] = grid, b
    for name in ('model_out', 'checkpoint_path'):
        values[name] = str(data_path(values[name])) if values[name] else ''
    return values


def _forgetting_problem(value) -> str | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f'must be a number in (0, 1], got {value!r}'
    if not 0 < value <= 1:
        return f'must be in (0, 1], got {value}'
    return None


class Estimator(Node):
    """Messages in, :class:`OnlineHerdEstimator` in the middle, messages out."""

    def __init__(self):
        super().__init__('estimator')
        self.cfg = cfg = read_parameters(self)
        self.core = OnlineHerdEstimator(
            cfg['agents'], cfg['dt'], cfg['law'], cfg['field_grid'], cfg['field_bounds'],
            cfg['forgetting'], cfg['p0'], cfg['min_visits'], cfg['interaction_radius'],
            cfg['profile_size'], robust=bool(cfg['robust']))
        self.counts = {'snapshots': 0, 'updates': 0, 'gaps': 0, 'backwards': 0,
                       'sessions': 1}
        self.clock_warning = ''
        self._resume()
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.params_pub = self.create_publisher(Float64MultiArray, '/herd/model/params', 10)
        self.noise_pub = self.create_publisher(Float64MultiArray, '/herd/model/noise', 10)
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
    def _validate_live(self, name, value):
        if name == 'forgetting':
            return _forgetting_problem(value)
        if name == 'robust' and not isinstance(value, bool):
            return f'must be true or false, got {value!r}'
        if name == 'model_out' and not (isinstance(value, str) and value.strip()):
            return 'must be a file name'
        return None

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
        path = self.cfg['checkpoint_path']
        if not path:
            return
        try:
            if self.core.load_checkpoint(path):
                self.get_logger().info(f'resumed from checkpoint {path} '
                                       f'({int(self.core.samples.max())} samples)')
            else:
                self.get_logger().info(f'no checkpoint at {path}: starting afresh')
        except HerdInputError as exc:
            self.get_logger().warning(f'{exc}; starting afresh (it will be overwritten)')

    def write_checkpoint(self):
        try:
            self.core.save_checkpoint(self.cfg['checkpoint_path'])
        except OSError as exc:
            self.get_logger().error(f'cannot write checkpoint: {exc}')

    def on_shutdown(self):
        """On a stop signal: the checkpoint, and the model learned so far (``model_out``),
        so nothing learned is lost however the node is stopped (short of ``kill -9``)."""
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
        n = len(self.core.agents)
        if len(msg.poses) != n:
            self._warn(f'/herd/poses has {len(msg.poses)} poses, expected {n} (agents): ignored')
            return
        t = stamp_to_seconds(msg.header.stamp)
        positions = np.array([[p.position.x, p.position.y] for p in msg.poses])
        result = self.core.add_snapshot(t, positions)
        self.counts['snapshots'] += 1
        if result.status == 'backwards' and -result.step > self.cfg['new_session_after_s']:
            self._new_session(t, -result.step)
            result = self.core.add_snapshot(t, positions)
        if result.status == 'backwards':
            self.counts['backwards'] += 1
            self._warn(f'snapshot at {t:.3f} s is not after the previous one: ignored')
            return
        if result.status == 'gap':
            self.counts['gaps'] += 1
            self._warn(f'snapshot step {result.step:.3f} s differs from dt {self.core.dt:g} s: '
                       f'the pair is not used')
        if result.status == 'updated':
            self.counts['updates'] += 1
            self.publish_params(msg.header.stamp)
        self.publish_prediction()

    def _new_session(self, t: float, back: float):
        """Data time went back by ``back`` s (more than ``new_session_after_s``): the same
        recording replayed again, or another. What was learned belongs to the old session:
        its checkpoint is set aside (renamed, not deleted) and the estimator starts afresh.
        A resume after a crash continues the data, so it never lands here."""
        path = self.cfg['checkpoint_path']
        aside = ''
        if path and os.path.isfile(path):
            root, ext = os.path.splitext(path)
            k = 1
            while os.path.exists(f'{root}.session-{k}{ext}'):
                k += 1
            aside = f'{root}.session-{k}{ext}'
            os.replace(path, aside)
        self.core.reset()
        self.counts['sessions'] += 1
        self.get_logger().info(
            f'data time went back {back:.0f} s (to {t:.3f}): a new session, learning afresh'
            + (f'; the previous checkpoint is kept as {aside}' if aside else ''))

    def _warn(self, text: str):
        self.clock_warning = text
        self.get_logger().warning(text, throttle_duration_sec=5.0)
        self.diag_pub.publish(diagnostic_array(self, [diagnostic_status(
            'estimator: herd clock', WARN, text, dict(self.counts))]))

    def publish_params(self, stamp=None):
        theta = self.core.theta
        n, p = theta.shape
        msg = Float64MultiArray()
        msg.layout.dim = [MultiArrayDimension(label='agent', size=n, stride=n * p),
                          MultiArrayDimension(label='param', size=p, stride=p)]
        msg.data = array.array('d', theta.ravel())
        self.params_pub.publish(msg)
        q = self.core.rls.noise_cov().reshape(n, 4)
        noise = Float64MultiArray()
        noise.layout.dim = [MultiArrayDimension(label='agent', size=n, stride=n * 4),
                            MultiArrayDimension(label='qxx_qxy_qyx_qyy', size=4, stride=4)]
        noise.data = array.array('d', q.ravel())
        self.noise_pub.publish(noise)

    def publish_prediction(self):
        pred = self.core.predict()
        if pred is None:
            return
        t, positions = pred
        msg = PoseArray()
        msg.header.stamp = seconds_to_stamp(t)
        msg.header.frame_id = self.cfg['frame_id']
        msg.poses = [_pose(x, y) for x, y in positions]
        self.pred_pub.publish(msg)
        self._last_prediction = positions

    # -- status ----------------------------------------------------------------------------
    def publish_status(self):
        d = self.core.diagnostics()
        sk = self.core.skill()
        statuses = [diagnostic_status(
            'estimator: herd clock', WARN if self.clock_warning else OK,
            self.clock_warning or 'snapshots on the clock', dict(self.counts)),
            diagnostic_status(
                'estimator: prediction skill', OK,
                'running one-step RMS (m) of the herd: model (predicted before each update) '
                'vs constant velocity vs stay-put',
                {'model_rms': sk['model_herd'],
                 'constant_velocity_rms': sk['constant_velocity_herd'],
                 'stay_put_rms': sk['stay_put_herd'],
                 'predictions': int(sk['predictions'].sum())})]
        for i, a in enumerate(self.core.agents):
            samples = int(d['samples'][i])
            level = OK if samples > 0 else WARN
            message = ('learning' if samples > 0 else 'no samples yet')
            if samples > 50 and not d['white'][i]:
                message = 'residual not white: the model misses something'
            statuses.append(diagnostic_status(f'estimator: {a}', level, message, {
                'samples': samples, 'residual_rms': float(d['residual_rms'][i]),
                'lag1_autocorrelation': float(d['lag1_autocorrelation'][i]),
                'white_band_95': float(d['white_band'][i]),
                'condition_P': float(d['condition'][i]),
                'skill_model_rms': float(sk['model'][i]),
                'skill_constant_velocity_rms': float(sk['constant_velocity'][i]),
                'skill_stay_put_rms': float(sk['stay_put'][i])}, hardware_id=a))
        self.clock_warning = ''
        self.diag_pub.publish(diagnostic_array(self, statuses))
        self.publish_markers()

    def publish_markers(self):
        frame = self.cfg['frame_id']
        centers = self.core.basis.centers
        field = self.core.mean_field(centers)
        spacing = float(np.mean(self.core.grid.spacing))
        top = float(np.max(np.hypot(field[:, 0], field[:, 1]))) if len(field) else 0.0
        scale = 0.8 * spacing / top if top > 0 else 0.0
        markers = [_points_marker(frame, 'centres', 0, centers, 0.2 * spacing,
                                  ColorRGBA(r=0.6, g=0.6, b=0.6, a=0.8))]
        for k, (c, g) in enumerate(zip(centers, field)):
            m = Marker(type=Marker.ARROW, action=Marker.ADD, ns='field', id=k)
            m.header.frame_id = frame
            m.points = [Point(x=float(c[0]), y=float(c[1])),
                        Point(x=float(c[0] + scale * g[0]), y=float(c[1] + scale * g[1]))]
            m.scale.x, m.scale.y, m.scale.z = 0.05 * spacing, 0.1 * spacing, 0.1 * spacing
            m.color = ColorRGBA(r=0.1, g=0.4, b=0.9, a=0.9)
            m.pose.orientation.w = 1.0
            markers.append(m)
        pred = getattr(self, '_last_prediction', None)
        if pred is not None:
            markers.append(_points_marker(frame, 'predictions', 0, np.nan_to_num(pred),
                                          0.1 * spacing, ColorRGBA(r=0.9, g=0.3, b=0.1, a=1.0)))
        self.marker_pub.publish(MarkerArray(markers=markers))

    # -- services --------------------------------------------------------------------------
    def on_save_model(self, request, response):
        try:
            path = self.core.save_model(self.cfg['model_out'], frame_id=self.cfg['frame_id'])
            response.success, response.message = True, str(Path(path).resolve())
        except (HerdInputError, OSError) as exc:
            response.success, response.message = False, str(exc)
        return response

    def on_reset(self, request, response):
        self.core.reset()
        self.get_logger().info('estimator reset: θ = θ₀, P = P₀, counters zero')
        response.success, response.message = True, 'reset'
        return response


def _pose(x: float, y: float) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y = float(x), float(y)
    pose.orientation.w = 1.0
    return pose


def _points_marker(frame, ns, mid, points, size, color) -> Marker:
    m = Marker(type=Marker.SPHERE_LIST, action=Marker.ADD, ns=ns, id=mid)
    m.header.frame_id = frame
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = float(size)
    m.color = color
    m.points = [Point(x=float(x), y=float(y)) for x, y in points]
    return m


def main(args=None):
    exit_process(run_node(Estimator, args=args))


if __name__ == '__main__':
    raise SystemExit(main())
