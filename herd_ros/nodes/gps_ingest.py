"""`gps_ingest` node: GPS collar fixes -> filtered odometry and one herd clock (issue 3).

Subscribes ``/herd/<agent>/fix`` (sensor_msgs/NavSatFix, sensor-data QoS: best effort,
volatile, keep last ``fix_queue_depth`` — 50 rather than 5, so a bag replayed faster than
real time or a busy moment of the node does not drop fixes) for every id of the ``agents``
parameter — or, with ``fix_topic`` set, one NavSatFix topic for every collar (a gateway's),
the collar named by ``header.frame_id`` (``<agent>``, ``<agent>_gps`` or ``<agent>/gps``;
keep last ``fix_queue_depth`` × collars). Publishes

* ``/herd/<agent>/odom`` (or every collar on ``odom_topic``, when set) (nav_msgs/Odometry)
  after every accepted fix: frame ``frame_id``,
  child ``<agent>``, stamped with the fix time; pose = filtered ENU position, twist = filtered
  ENU velocity (the child frame is axis-aligned with ``map``: orientation is the identity,
  since a collar measures no heading), both with their covariance from the filter. Unobserved
  entries (z, roll, pitch, yaw and their rates) carry the variance :data:`UNOBSERVED_VARIANCE`.
* ``/herd/poses`` (geometry_msgs/PoseArray, ``agents`` order) for every tick of the herd
  clock, stamped with the tick: an agent with an accepted fix within ``stale_after`` s of
  data time carries the filter's prediction to the tick; a stale agent (silent longer, or
  never initialised) gets a **NaN** position (x = y = z = NaN, identity orientation) —
  missing, never an extrapolation — so consumers must check ``isfinite``.
* ``/diagnostics`` every ``diagnostics_period_s`` s of wall time (the only wall-time timer):
  one status per collar (counters per outcome, stale flag, last rejection) — WARN if a fix
  was rejected since the last report or the collar is stale, OK otherwise — and one for the
  node (datum, herd time, ticks published, message errors).

**Scale.** One topic per collar costs DDS endpoints and discovery that grow faster than the
herd (building 20 000 endpoints in one process took 177 s, discovery of them 11 minutes);
the shared topics ``fix_topic`` / ``odom_topic`` serve 10 000 collars at 1 Hz. Messages
cross the edge serialized (``raw=True`` subscriptions, bytes published) and are converted a
batch at a time by :mod:`herd_ros.io.cdr`.

The numerics are the offline path's (:mod:`herd_ros.ingest.pipeline`): the subscription
callbacks only queue each serialized NavSatFix; every ``batch_period_s`` (5 ms
of wall time) the fixes received are decoded and handed at once to
:func:`~herd_ros.ingest.geodesy.geodetic_to_enu` (NaN altitude -> the datum's), the compiled
:class:`~herd_ros.ingest.collar_bank.CollarBank` (the filter of every collar in arrays;
rejection reasons ``no_fix``, ``nan``, ``time``, ``speed``, ``gate``, ``unconfirmed``) and the
streaming :class:`~herd_ros.ingest.herd_clock.BatchHerdClock` in data time (header stamps,
never wall time). A tick costs O(collars) compiled work, not a Python loop over the collars.
Fed the same fixes in stamp order, the node publishes the snapshots of
``trajectory_from_fixes(..., smoother='none', trim=False)``.

Datum: the ``datum`` parameter, or (empty) the earliest-stamped *valid* fix (status not
NO_FIX, finite lat/lon) — chosen by :func:`~herd_ros.ingest.pipeline.choose_datum`, the
offline rule. Fixes are held until every collar has sent a valid fix, or ``stale_after`` s
of data time have passed since the first valid one, then processed in stamp order; so the
datum does not depend on which callback ran first (navsat_transform's race) and a NO_FIX or
NaN fix never becomes it. It is logged once.

Two guards keep one wrong stamp from hanging the clock (they have no offline counterpart):
a stamp more than ``max_stamp_ahead_s`` s ahead of the wall clock is rejected (reason
``future``, counted by the node), and a jump of the herd's data time by more than
``max_clock_jump_s`` s restarts the herd clock at the new time instead of publishing every
tick in between (logged, counted).

Bad messages never stop the node: one that does not decode, or any exception while handling
one, is caught, counted (``message_errors``) and reported as a WARN; a fix on ``fix_topic``
whose frame names no collar is counted (``unknown_collar_fixes``, the last frame named).
"""
from __future__ import annotations

import math
import time

import numpy as np
import pandas as pd
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import NavSatFix

from herd_ros.errors import HerdInputError
from herd_ros.ingest.collar_bank import OUTCOMES, CollarBank
from herd_ros.ingest.collar_filter import COUNTERS, STATUS_NO_FIX, FilterParams
from herd_ros.ingest.geodesy import geodetic_to_enu
from herd_ros.ingest.herd_clock import BatchHerdClock
from herd_ros.ingest.motion_refit import MotionRefitter, fix_variance, process_with_refits
from herd_ros.ingest.pipeline import choose_datum, refit_config, with_walk
from herd_ros.io.cdr import (NavSatFixes, OdometryEncoder, concat_fixes, decode_navsatfixes,
                             encode_pose_array, no_fixes, take_fixes)
from herd_ros.model.model_file import check_agent_id
from herd_ros.nodes.ros_common import (OK, WARN, LiveParameters, ParameterError,
                                       declare_parameters, describe_remaining_parameters,
                                       diagnostic_array, diagnostic_status, exit_process,
                                       number_problem, refresh_status, run_node,
                                       wall_timer)
from herd_ros.params.gps_ingest import PARAMS as DEFAULTS

#: Variance (m², rad², ...) of the Odometry entries a GPS collar does not observe.
UNOBSERVED_VARIANCE = 1e6

#: history depth of each /herd/<agent>/odom publisher (of odom_topic: this times the collars)
ODOM_DEPTH = 10

EXECUTORS = ('events', 'single_threaded')
MOTION_MODELS = ('fit', 'fixed')


#: The node parameters that are :class:`FilterParams` fields (same names).
FILTER_FIELDS = ('accel_std', 'velocity_tau', 'default_position_std', 'position_std_floor',
                 'gate_probability', 'max_speed', 'cruise_speed', 'sprint_s', 'stale_after',
                 'initial_velocity_std', 'confirm_fixes', 'reacquire_fixes',
                 'confirm_fixes_lost', 'reinit_after_gap', 'walk_probability')


class GpsIngestConfig:
    """Validated ``gps_ingest`` parameters; raises :class:`ParameterError` naming the one
    that is wrong."""

    def __init__(self, p: dict):
        agents = p['agents']
        if isinstance(agents, str) or not list(agents):
            raise ParameterError(f'agents must be a non-empty list of collar ids, got '
                                 f'{agents!r}')
        try:
            self.agents = [check_agent_id(a) for a in agents]
        except HerdInputError as exc:
            raise ParameterError(f'agents: {exc}') from None
        if len(set(self.agents)) != len(self.agents):
            raise ParameterError(f'agents must be distinct, got {self.agents}')
        datum = list(p['datum'])
        if datum:
            try:
                self.datum = choose_datum(None, [float(v) for v in datum])
            except (HerdInputError, TypeError, ValueError):
                raise ParameterError(f'datum must be [] (first valid fix), [lat, lon] or '
                                     f'[lat, lon, alt] (finite degrees within ±90/±180, '
                                     f'metres), got {datum!r}') from None
        else:
            self.datum = None
        for name in ('dt', 'diagnostics_period_s', 'max_stamp_ahead_s', 'max_clock_jump_s'):
            value = _number(p, name)
            if not (math.isfinite(value) and value > 0):
                raise ParameterError(f'{name} must be a positive number of seconds, got '
                                     f'{p[name]!r}')
            setattr(self, name, value)
        filt = {name: _number(p, name) for name in FILTER_FIELDS}
        for name in ('confirm_fixes', 'reacquire_fixes', 'confirm_fixes_lost'):
            filt[name] = int(filt[name])
        if filt['initial_velocity_std'] == 0.0:
            filt['initial_velocity_std'] = None
        try:
            self.filter_params = FilterParams(**filt)
        except HerdInputError as exc:
            raise ParameterError(str(exc).replace('filter parameter ', '')) from None
        if p['motion_model'] not in MOTION_MODELS:
            raise ParameterError(f'motion_model must be one of {", ".join(MOTION_MODELS)}, '
                                 f'got {p["motion_model"]!r}')
        self.motion_model = p['motion_model']
        window = p['motion_window']
        if isinstance(window, bool) or not isinstance(window, int) or window < 20:
            raise ParameterError(f'motion_window must be an integer ≥ 20, got {window!r}')
        self.refit = None
        if self.motion_model == 'fit':
            self.filter_params = with_walk(self.filter_params)
            self.refit = refit_config(self.filter_params, window)
        self.frame_id = str(p['frame_id']).strip()
        if not self.frame_id:
            raise ParameterError('frame_id must be a non-empty frame name')
        if p['executor'] not in EXECUTORS:
            raise ParameterError(f'executor must be one of {", ".join(EXECUTORS)}, got '
                                 f'{p["executor"]!r}')
        self.executor = p['executor']
        self.batch_period_s = _number(p, 'batch_period_s')
        self.diagnostics_max_collars = int(p['diagnostics_max_collars'])
        depth = p['fix_queue_depth']
        if isinstance(depth, bool) or not isinstance(depth, int) or depth < 1:
            raise ParameterError(f'fix_queue_depth must be an integer ≥ 1, got {depth!r}')
        self.fix_topic = _topic(p, 'fix_topic')
        self.odom_topic = _topic(p, 'odom_topic')
        if self.fix_topic:
            depth = min(depth * len(self.agents), 10**7)
        self.fix_qos = QoSProfile(depth=depth, reliability=qos_profile_sensor_data.reliability,
                                  durability=qos_profile_sensor_data.durability,
                                  history=qos_profile_sensor_data.history)
        self.odom_depth = ODOM_DEPTH * (len(self.agents) if self.odom_topic else 1)


def _topic(p: dict, name: str) -> str:
    """'' or a valid absolute or relative topic name."""
    topic = str(p[name]).strip()
    if topic:
        from rclpy.validate_full_topic_name import validate_full_topic_name
        try:
            validate_full_topic_name(topic if topic.startswith('/') else '/' + topic)
        except Exception as exc:    # rclpy's InvalidTopicNameException
            raise ParameterError(f'{name} must be empty or a topic name, got {topic!r} '
                                 f'({str(exc).splitlines()[0].rstrip(":")})') from None
    return topic


def _number(p: dict, name: str) -> float:
    try:
        return float(p[name])
    except (TypeError, ValueError):
        raise ParameterError(f'{name} must be a number, got {p[name]!r}') from None


# -- message conversion at the edge -----------------------------------------------------------
def collar_frames(agents) -> dict:
    """header.frame_id -> collar index on a shared fix topic: ``<agent>`` and the sensor
    frames ``<agent>_gps`` (what ``herd-ros import`` writes) and ``<agent>/gps``."""
    frames = {}
    for i, agent in enumerate(agents):
        for frame in (agent, f'{agent}_gps', f'{agent}/gps'):
            frames.setdefault(frame, i)
    return frames


#: what a rejection means, for diagnostics and logs
REJECTION_TEXT = {
    'no_fix': 'status is STATUS_NO_FIX',
    'nan': 'latitude or longitude is not finite',
    'time': 'stamp not after the last fix (time going backwards, or a duplicate)',
    'speed': 'beyond reach of the track (max_speed, cruise_speed, sprint_s): an outlier '
             'unless more follow',
    'gate': 'outside the Mahalanobis gate',
    'unconfirmed': 'track lost or not started: waiting for consistent fixes',
}


class GpsIngest(Node):
    def __init__(self):
        super().__init__('gps_ingest')
        self.cfg = cfg = GpsIngestConfig(declare_parameters(self, DEFAULTS))
        CollarBank.warm_up()           # compiled code loaded before the first fix
        BatchHerdClock.warm_up()
        self.bank = CollarBank(len(cfg.agents), cfg.filter_params)
        self.refitter = (MotionRefitter(len(cfg.agents), cfg.refit) if cfg.refit is not None
                         else None)
        self.clock = self._new_clock()
        self._frames = collar_frames(cfg.agents)      # frame_id -> collar (fix_topic)
        self._inbox: list[tuple] = []     # (collar index, -1 on fix_topic; serialized fix)
        self._diagnostics_job = None
        self._diagnostics_next = 0                 # first collar of the next report
        self._statuses = [None] * len(cfg.agents)  # each collar's status, reused
        self._odom = OdometryEncoder(cfg.agents, cfg.frame_id, UNOBSERVED_VARIANCE)
        self.datum = cfg.datum
        self._pending: list[tuple] = []   # (collars, NavSatFixes) held until the datum is chosen
        self._pending_valid: dict[int, float] = {}  # collar -> first valid stamp held
        self._pending_latest = -math.inf            # latest stamp held
        self.rejected_future = dict.fromkeys(cfg.agents, 0)
        self.last_rejection = dict.fromkeys(cfg.agents, '')
        self._reported = {a: dict.fromkeys(COUNTERS, 0) for a in cfg.agents}
        self.message_errors = 0
        self.unknown_collar_fixes = 0
        self.last_unknown_frame = ''
        self.clock_restarts = 0
        self.ticks_published = 0
        self._errors_reported = (0, 0)     # message_errors, unknown_collar_fixes
        if cfg.odom_topic:
            shared = self.create_publisher(Odometry, cfg.odom_topic, cfg.odom_depth).publish
            self._odom_publish = [shared] * len(cfg.agents)
        else:
            self._odom_publish = [self.create_publisher(Odometry, f'/herd/{a}/odom',
                                                        cfg.odom_depth).publish
                                  for a in cfg.agents]
        self.poses_pub = self.create_publisher(PoseArray, '/herd/poses',
                                               QoSProfile(depth=100))
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # messages stay serialized at the edge; herd_ros.io.cdr converts them in batches
        if cfg.fix_topic:
            self.create_subscription(NavSatFix, cfg.fix_topic, lambda data: self.on_fix(-1, data),
                                     cfg.fix_qos, raw=True)
        else:
            for i, a in enumerate(cfg.agents):
                self.create_subscription(NavSatFix, f'/herd/{a}/fix',
                                         lambda data, i=i: self.on_fix(i, data), cfg.fix_qos,
                                         raw=True)
        wall_timer(self, cfg.diagnostics_period_s, self.publish_diagnostics)
        if cfg.batch_period_s > 0:
            wall_timer(self, cfg.batch_period_s, self.drain)
        self.executor_kind = cfg.executor        # run_node builds it
        describe_remaining_parameters(self, 'not a gps_ingest parameter (ignored)')
        LiveParameters(self, self._validate_live, self._apply_live)
        if self.datum is not None:
            self._log_datum('parameter')
        self.get_logger().info(f'{len(cfg.agents)} collars, herd clock dt {cfg.dt:g} s, '
                               f'datum {"from parameter" if self.datum else "first valid fix"}'
                               f', fixes on {cfg.fix_topic or "/herd/<agent>/fix"}, odometry '
                               f'on {cfg.odom_topic or "/herd/<agent>/odom"}, executor '
                               f'{cfg.executor}')

    # -- live parameters (accel_std, max_speed, cruise_speed, sprint_s) --------------------
    def _live_filter_params(self, name, value):
        import dataclasses
        if name == 'accel_std' and self.cfg.refit is not None:
            # fitted collars: the parameter is the walk component's (and the prior's)
            p = dataclasses.replace(self.cfg.filter_params, walk_accel_std=None,
                                    walk_velocity_tau=None, accel_std=float(value),
                                    velocity_tau=self.cfg.filter_params.walk[1])
            return with_walk(p)
        return dataclasses.replace(self.cfg.filter_params, **{name: float(value)})

    def _validate_live(self, name, value):
        problem = number_problem(value, strict=False)
        if problem:
            return problem
        try:
            self._live_filter_params(name, value)
        except HerdInputError as exc:
            return str(exc)
        return None

    def _apply_live(self, name, value):
        """The bank reads its parameters at every batch: the next fix uses the new value."""
        self.cfg.filter_params = self._live_filter_params(name, value)
        self.bank.params = self.cfg.filter_params
        if name == 'accel_std':
            if self.refitter is None:
                self.bank.accel_std[:] = self.cfg.filter_params.accel_std
            else:       # the collars not fitted yet move by the new prior
                unfitted = np.array([f is None for f in self.refitter.fits])
                self.bank.accel_std[unfitted] = self.cfg.filter_params.accel_std
                w = self.cfg.filter_params.walk
                self.refitter.config.walk = (w[0], w[1],
                                             self.cfg.filter_params.walk_probability)

    # -- one fix ------------------------------------------------------------------------
    def on_fix(self, collar: int, data: bytes):
        """A serialized NavSatFix of collar ``collar`` (-1: named by its frame, fix_topic):
        queued for the next batch (:meth:`drain`)."""
        self._inbox.append((collar, data))
        if self.cfg.batch_period_s == 0 or len(self._inbox) >= 100_000:
            self.drain()

    def on_shutdown(self):
        """Stop signal: filter and publish the fixes still waiting for their batch."""
        self.drain()

    def _new_clock(self) -> BatchHerdClock:
        p = self.cfg.filter_params
        return BatchHerdClock(self.cfg.agents, self.cfg.dt, p.stale_after,
                              self.bank.accel_std, self.bank.velocity_tau)

    def drain(self):
        """Decode and filter the fixes received since the last batch (:meth:`process_batch`);
        then a step of the diagnostics being built, if any."""
        if not self._inbox:
            self._advance_diagnostics()
            return
        inbox, self._inbox = self._inbox, []
        try:
            collars, fixes = self._decode(inbox)
            if self.datum is None and len(collars):
                collars, fixes = self._hold(collars, fixes)
            if len(collars):
                self.process_batch(collars, fixes)
        except Exception as exc:   # a bad batch must never stop the node
            self.message_errors += len(inbox)
            self.get_logger().warn(f'{len(inbox)} fixes dropped ({type(exc).__name__}: '
                                   f'{exc})', throttle_duration_sec=5.0)
        self._advance_diagnostics()

    def _decode(self, inbox) -> tuple[np.ndarray, NavSatFixes]:
        """Serialized fixes -> (collar indices, decoded fixes) of those that decode, name a
        collar and are not stamped in the future (each of the others counted)."""
        fixes, bad = decode_navsatfixes([data for _, data in inbox])
        if bad:
            self.message_errors += len(bad)
            self.get_logger().warn(f'{len(bad)} fixes dropped: not a NavSatFix ({bad[0][1]})',
                                   throttle_duration_sec=5.0)
        m = len(fixes.stamp)
        keep = np.ones(m, bool)
        if self.cfg.fix_topic:
            frames = self._frames
            collars = np.fromiter((frames.get(f, -1) for f in fixes.frame_id), np.int64, m)
            unknown = np.flatnonzero(collars < 0)
            if len(unknown):
                keep[unknown] = False
                self.unknown_collar_fixes += len(unknown)
                self.last_unknown_frame = fixes.frame_id[unknown[-1]]
                self.get_logger().warn(f'{len(unknown)} fixes on {self.cfg.fix_topic} name no '
                                       f'collar of agents (frame_id '
                                       f'{self.last_unknown_frame!r})',
                                       throttle_duration_sec=5.0)
        else:
            skip = {k for k, _ in bad}
            collars = np.fromiter((c for k, (c, _) in enumerate(inbox) if k not in skip),
                                  np.int64, m)
        ahead = fixes.stamp > time.time() + self.cfg.max_stamp_ahead_s
        future = np.flatnonzero(keep & ahead)
        for k in future.tolist():
            agent = self.cfg.agents[collars[k]]
            self.rejected_future[agent] += 1
            self.last_rejection[agent] = (f'future: stamp {fixes.stamp[k]:.3f} is more than '
                                          f'max_stamp_ahead_s ahead of the wall clock')
        keep[future] = False
        if keep.all():
            return collars, fixes
        return collars[keep], take_fixes(fixes, keep)

    def process_batch(self, idx: np.ndarray, fixes: NavSatFixes):
        """Filter fixes of collars ``idx`` (in arrival order) with the collar bank, publish
        the odometry of the accepted ones and the herd snapshots they complete."""
        m = len(idx)
        agent_of = self.cfg.agents
        stamp = fixes.stamp
        lat0, lon0, alt0 = self.datum
        with np.errstate(invalid='ignore'):
            e, n, _ = geodetic_to_enu(fixes.lat, fixes.lon, fixes.alt, lat0, lon0, alt0,
                                      nan_alt=alt0)
        if self.refitter is None:
            batch = self.bank.process(idx, stamp, e, n, fixes.status,
                                      self.bank.measurement_covariances(fixes.cov_type,
                                                                        fixes.cov, idx))
            motion = None
        else:
            var = fix_variance(fixes.cov_type, fixes.cov[:, 0], fixes.cov[:, 4],
                               self.cfg.filter_params.position_std_floor)
            batch, motion = process_with_refits(self.bank, self.refitter, idx, stamp, e, n,
                                                fixes.status, fixes.cov_type, fixes.cov, var)
        accepted = batch.accepted
        frame = self.cfg.frame_id
        done = np.flatnonzero(accepted)
        publish = self._odom_publish
        for i, data in zip(idx[done].tolist(),
                           self._odom.encode(idx[done], stamp[done], batch.x[done],
                                             batch.P[done])):
            publish[i](data)
        rejected = np.flatnonzero(~accepted).tolist()
        for k in rejected:
            agent, reason = agent_of[idx[k]], OUTCOMES[batch.outcome[k]]
            detail = REJECTION_TEXT[reason]
            if reason == 'gate':
                detail += f' (distance² {batch.mahalanobis2[k]:.1f})'
            self.last_rejection[agent] = f'{reason}: {detail}'
        if rejected:
            # one (throttled) line per batch: a throttled call still costs ~1 ms, and at the
            # start every collar's first fix waits for confirmation (1 000 calls measured
            # as a 0.5 s stall of the first batches)
            k = rejected[0]
            more = f' (and {len(rejected) - 1} more in this batch)' if len(rejected) > 1 else ''
            self.get_logger().warn(f'{agent_of[idx[k]]}: fix at {stamp[k]:.3f} rejected '
                                   f'({self.last_rejection[agent_of[idx[k]]]}){more}',
                                   throttle_duration_sec=5.0)
        # the herd clock; a forward jump of data time beyond max_clock_jump_s restarts it
        finite = np.where(np.isfinite(stamp), stamp, -np.inf)
        before = np.maximum.accumulate(np.r_[self.clock.herd_time, finite])[:-1]
        jumps = np.flatnonzero(np.isfinite(before)
                               & (finite > before + self.cfg.max_clock_jump_s)).tolist()
        start = 0
        for j in jumps + [m]:
            if j > start:
                sl = slice(start, j)
                for snap in self.clock.observe(idx[sl], stamp[sl], accepted[sl],
                                               batch.x[sl], batch.P[sl],
                                               None if motion is None else motion[sl]):
                    self.poses_pub.publish(encode_pose_array(snap.time, frame,
                                                             snap.positions))
                    self.ticks_published += 1
            if j < m:
                self.clock_restarts += 1
                self.get_logger().warn(f'data time jumped {stamp[j] - before[j]:.0f} s '
                                       f'(> max_clock_jump_s): herd clock restarted at '
                                       f'{stamp[j]:.3f}')
                self.clock = self._new_clock()
                start = j

    # -- datum from the first valid fix -----------------------------------------------
    def _hold(self, collars: np.ndarray, fixes: NavSatFixes):
        """Hold fixes until the datum can be chosen; then return every fix held, in stamp
        order (else nothing)."""
        self._pending.append((collars, fixes))
        self._pending_latest = max(self._pending_latest, float(fixes.stamp.max()))
        valid = ((fixes.status != STATUS_NO_FIX) & np.isfinite(fixes.lat)
                 & np.isfinite(fixes.lon))
        for k in np.flatnonzero(valid).tolist():
            self._pending_valid.setdefault(int(collars[k]), float(fixes.stamp[k]))
        nothing = (np.zeros(0, np.int64), no_fixes())
        if not self._pending_valid:
            held = sum(len(c) for c, _ in self._pending)
            while held > 100 * len(self.cfg.agents) and len(self._pending) > 1:
                dropped = len(self._pending.pop(0)[0])   # nothing valid yet: bound memory
                self.message_errors += dropped
                held -= dropped
            return nothing
        everyone = len(self._pending_valid) == len(self.cfg.agents)
        waited = (self._pending_latest - min(self._pending_valid.values())
                  > self.cfg.filter_params.stale_after)
        if everyone or waited:
            return self._choose_datum()
        return nothing

    def _choose_datum(self):
        collars = np.concatenate([c for c, _ in self._pending])
        held = concat_fixes([f for _, f in self._pending])
        table = pd.DataFrame({'time': held.stamp,
                              'agent': [self.cfg.agents[i] for i in collars.tolist()],
                              'lat': held.lat, 'lon': held.lon, 'alt': held.alt,
                              'status': held.status})
        self.datum = choose_datum(table)
        self._log_datum('first valid fix')
        self._pending = []
        order = np.argsort(held.stamp, kind='stable')
        return collars[order], take_fixes(held, order)

    def _log_datum(self, source: str):
        self.get_logger().info('datum (%s): lat %.9f lon %.9f alt %.3f'
                               % ((source,) + tuple(self.datum)))

    # -- diagnostics --------------------------------------------------------------------
    #: collar statuses built and published (one DiagnosticArray) per step of the job
    DIAGNOSTICS_STEP = 50

    def publish_diagnostics(self):
        """Start the diagnostics of this period. With many collars, building the message
        (a status of a dozen values per collar: ~45 ms for 1 000 collars, measured) and
        converting it for DDS (~0.1 s) would hold every fix back for that long, so the batch
        timer builds and publishes it :data:`DIAGNOSTICS_STEP` collars per DiagnosticArray
        at a time, between batches; the node's own status comes in the last one (without
        batches, all at once). Monitors key statuses by name, so several arrays per period
        are one report."""
        if self._diagnostics_job is not None:
            return                       # the previous one is still being built
        self._diagnostics_job = self._diagnostics()
        if self.cfg.batch_period_s == 0:
            self._advance_diagnostics(until_done=True)

    def _advance_diagnostics(self, until_done: bool = False):
        job = self._diagnostics_job
        if job is None:
            return
        try:
            while True:
                next(job)
                if not until_done:
                    return
        except StopIteration:
            self._diagnostics_job = None

    def _diagnostics(self):
        herd_time = self.clock.herd_time
        statuses = []
        stale_all = (self.bank.is_stale(herd_time) if math.isfinite(herd_time)
                     else np.zeros(len(self.cfg.agents), bool))
        n = len(self.cfg.agents)
        share = min(n, self.cfg.diagnostics_max_collars)
        first = self._diagnostics_next % n
        self._diagnostics_next = (first + share) % n
        for j in range(share):
            i = (first + j) % n
            agent = self.cfg.agents[i]
            if j and j % self.DIAGNOSTICS_STEP == 0:
                self.diag_pub.publish(diagnostic_array(self, statuses))
                statuses = []
                yield
            counters = self.bank.counter_dict(i)
            counters['rejected_future'] = self.rejected_future[agent]
            previous = self._reported[agent]
            rejected_now = any(counters[k] > previous.get(k, 0) for k in counters
                               if k.startswith('rejected_'))
            self._reported[agent] = counters
            stale = bool(stale_all[i])
            if rejected_now:
                level, message = WARN, f'rejected {self.last_rejection[agent]}'
            elif stale:
                level, message = WARN, ('stale: no accepted fix yet'
                                        if not self.bank.initialised[i]
                                        else f'stale: silent for more than '
                                        f'{self.cfg.filter_params.stale_after:g} s, missing '
                                        f'(NaN) in /herd/poses')
            else:
                level, message = OK, 'ok'
            values = dict(counters)
            values.update(stale=stale, last_fix=float(self.bank.t[i]),
                          last_rejection=self.last_rejection[agent])
            self._statuses[i] = refresh_status(self._statuses[i], f'gps_ingest: {agent}',
                                               level, message, values, hardware_id=agent)
            statuses.append(self._statuses[i])
        new_bad = self.message_errors - self._errors_reported[0]
        new_unknown = self.unknown_collar_fixes - self._errors_reported[1]
        self._errors_reported = (self.message_errors, self.unknown_collar_fixes)
        problems = ([f'{new_bad} bad message{"s" * (new_bad > 1)} dropped'] if new_bad
                    else []) + ([f'{new_unknown} fix{"es" * (new_unknown > 1)} of unknown '
                                 f'collars dropped'] if new_unknown else [])
        totals = self.bank.counters.sum(axis=0)
        node_values = {'herd_time': herd_time, 'ticks_published': self.ticks_published,
                       'fixes': int(totals[:-1].sum()) + sum(self.rejected_future.values()),
                       'accepted': int(totals[0]), 'stale_collars': int(stale_all.sum()),
                       'message_errors': self.message_errors,
                       'clock_restarts': self.clock_restarts,
                       'unknown_collar_fixes': self.unknown_collar_fixes,
                       'last_unknown_frame': self.last_unknown_frame,
                       'fixes_waiting_for_datum': sum(len(c) for c, _ in self._pending),
                       'datum': ('waiting for the first valid fix' if self.datum is None
                                 else ', '.join(f'{v:.9f}' for v in self.datum))}
        statuses.append(diagnostic_status(
            'gps_ingest', WARN if problems else OK,
            ('; '.join(problems) + ' since the last report') if problems else
            f'{n} collars' + (f', statuses of {share} per period in turn' if share < n else ''),
            node_values))
        self.diag_pub.publish(diagnostic_array(self, statuses))


def main(args=None):
    exit_process(run_node(GpsIngest, args=args))


if __name__ == '__main__':
    main()
