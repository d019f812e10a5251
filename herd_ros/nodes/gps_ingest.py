"""`gps_ingest` node: GPS collar fixes -> filtered odometry and one herd clock (issue 3).

Subscribes ``/herd/<agent>/fix`` (NavSatFix, sensor-data QoS, keep last ``fix_queue_depth``)
per collar of ``agents``, or one ``fix_topic`` for every collar (a gateway's; the collar
named by ``header.frame_id``: ``<agent>``, ``<agent>_gps`` or ``<agent>/gps``, the id also
as it was before it was made a ROS name, ``4262-8483`` for ``id_4262_8483``:
:mod:`herd_ros.agent_ids`). Publishes

* ``/herd/<agent>/odom`` (or ``odom_topic``) after every accepted fix: frame ``frame_id``,
  child ``<agent>``, stamped with the fix; filtered ENU position and velocity with their
  covariance (identity orientation: a collar measures no heading; unobserved entries carry
  :data:`UNOBSERVED_VARIANCE`);
* ``/herd/poses`` (PoseArray, ``agents`` order) at every tick of the herd clock (data time):
  each collar's prediction to the tick, or **NaN** for a stale one (silent longer than
  ``stale_after``, or not started): missing, never an extrapolation;
* ``/diagnostics`` every ``diagnostics_period_s`` (wall time): per collar its counters, stale
  flag and last rejection (WARN on a rejection or stale), and the node's totals.

The work is :class:`~herd_ros.ingest.fix_stream.FixStream` (no ROS; datum, stamp guards,
the compiled collar bank with its motion refits, the herd clock): the callbacks queue each
serialized fix; every ``batch_period_s`` the batch is decoded (:mod:`herd_ros.io.cdr`) and
pushed into the stream at once. Fed the same fixes in stamp order the node publishes the
snapshots of ``trajectory_from_fixes(..., smoother='none', trim=False)``. With more than
~1000 collars use ``fix_topic``/``odom_topic``: DDS endpoints and their discovery grow faster
than the herd (20 000 endpoints took 177 s to build and 11 min to discover).

Bad messages never stop the node: one that does not decode, or any exception while handling
one, is caught, counted (``message_errors``) and reported as a WARN; a fix on ``fix_topic``
whose frame names no collar is counted (``unknown_collar_fixes``, the last frame named).
"""
from __future__ import annotations

import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import NavSatFix

from herd_ros.ingest.collar_filter import COUNTERS
from herd_ros.ingest.fix_stream import FixStream, collar_frames, datum_text, frame_collar
from herd_ros.io.cdr import OdometryEncoder, decode_navsatfixes, encode_pose_array, take_fixes
from herd_ros.nodes.ros_common import (OK, WARN, LiveParameters, declare_parameters,
                                       describe_remaining_parameters, diagnostic_array,
                                       diagnostic_status, exit_process, number_problem,
                                       refresh_status, run_node, wall_timer)
from herd_ros.params.gps_ingest import PARAMS as DEFAULTS, GpsIngestConfig

#: Variance (m², rad², ...) of the Odometry entries a GPS collar does not observe.
UNOBSERVED_VARIANCE = 1e6


class GpsIngest(Node):
    """The ``gps_ingest`` node (module docstring)."""
    #: collar statuses built and published (one DiagnosticArray) per step of the job: with
    #: many collars, building a report (~45 ms per 1 000 collars, ~0.1 s to convert) at once
    #: would hold every fix back, so it is built between batches
    DIAGNOSTICS_STEP = 50

    def __init__(self):
        super().__init__('gps_ingest')
        self.cfg = cfg = GpsIngestConfig(declare_parameters(self, DEFAULTS))
        fix_qos = QoSProfile(depth=cfg.fix_depth, history=qos_profile_sensor_data.history,
                             reliability=qos_profile_sensor_data.reliability,
                             durability=qos_profile_sensor_data.durability)
        FixStream.warm_up()
        # with a batch timer the refits run in the background (it collects them)
        self.stream = FixStream(cfg.agents, cfg.dt, cfg.filter_params, cfg.refit, cfg.datum,
                                cfg.max_stamp_ahead_s, cfg.max_clock_jump_s,
                                cfg.silence_grace_s,
                                refit_in_background=cfg.batch_period_s > 0)
        self._frames = collar_frames(cfg.agents)      # frame_id -> collar (fix_topic)
        self._inbox: list[tuple] = []     # (collar index, -1 on fix_topic; serialized fix)
        self._diagnostics_job, self._diagnostics_next = None, 0
        self._statuses = [None] * len(cfg.agents)  # each collar's status, reused
        self._reported = [dict.fromkeys(COUNTERS, 0) for _ in cfg.agents]
        self._odom = OdometryEncoder(cfg.agents, cfg.frame_id, UNOBSERVED_VARIANCE)
        self.message_errors = self.unknown_collar_fixes = 0
        self.last_unknown_frame = ''
        self._errors_reported = (0, 0)     # message_errors, unknown_collar_fixes
        if cfg.odom_topic:
            shared = self.create_publisher(Odometry, cfg.odom_topic, cfg.odom_depth).publish
            self._odom_publish = [shared] * len(cfg.agents)
        else:
            self._odom_publish = [self.create_publisher(Odometry, f'/herd/{a}/odom',
                                                        cfg.odom_depth).publish
                                  for a in cfg.agents]
        self.poses_pub = self.create_publisher(PoseArray, '/herd/poses', QoSProfile(depth=100))
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # messages stay serialized at the edge; herd_ros.io.cdr converts them in batches
        if cfg.fix_topic:
            self.create_subscription(NavSatFix, cfg.fix_topic, lambda data: self.on_fix(-1, data),
                                     fix_qos, raw=True)
        else:
            for i, a in enumerate(cfg.agents):
                self.create_subscription(NavSatFix, f'/herd/{a}/fix',
                                         lambda data, i=i: self.on_fix(i, data), fix_qos,
                                         raw=True)
        wall_timer(self, cfg.diagnostics_period_s, self.publish_diagnostics)
        if cfg.batch_period_s > 0:
            wall_timer(self, cfg.batch_period_s, self.drain)
        if cfg.silence_grace_s > 0:
            # the ticks that wait only for a quiet collar's grace, when no fix comes
            wall_timer(self, max(0.05, cfg.silence_grace_s / 4), self.poll_clock)
        self.executor_kind = cfg.executor        # run_node builds it
        describe_remaining_parameters(self, 'not a gps_ingest parameter (ignored)')
        LiveParameters(self, lambda name, value: (number_problem(value, strict=False)
                                                  or self.stream.check_param(name, value)),
                       lambda name, value: self.stream.set_param(name, value))
        if cfg.datum is not None:
            self.get_logger().info(datum_text(cfg.datum, 'parameter'))
        self.get_logger().info(f'{len(cfg.agents)} collars, herd clock dt {cfg.dt:g} s, '
                               f'datum {"from parameter" if cfg.datum else "first valid fix"}'
                               f', fixes on {cfg.fix_topic or "/herd/<agent>/fix"}, odometry '
                               f'on {cfg.odom_topic or "/herd/<agent>/odom"}, executor '
                               f'{cfg.executor}')

    def on_fix(self, collar: int, data: bytes):
        """A serialized NavSatFix of collar ``collar`` (-1: named by its frame, fix_topic):
        queued for the next batch (:meth:`drain`)."""
        self._inbox.append((collar, data))
        if self.cfg.batch_period_s == 0 or len(self._inbox) >= 100_000:
            self.drain()

    def poll_clock(self):
        """No fix for a while: publish the herd snapshots that waited only for the
        ``silence_grace_s`` of a collar gone quiet (the fixes queued go first)."""
        if self._inbox:
            return
        out = self.stream.poll(time.time())
        if out.snapshots or out.odometry or out.log:   # (fixes a refit released, too)
            self._publish(out)

    def on_shutdown(self):
        """Stop signal: filter and publish the fixes still waiting for their batch, and
        those waiting for a refit running in the background."""
        self.drain()
        if self.stream.background is not None:
            self._publish(self.stream.collect(time.time(), wait=True))
            self.stream.background.close()

    def drain(self):
        """Decode the fixes received since the last batch, push them into the stream and
        publish what it gives back (with no new fix: what the refits finished in the
        background released); then a step of the diagnostics being built, if any."""
        if self._inbox or self.stream.refits_unfinished:
            inbox, self._inbox = self._inbox, []
            try:
                if inbox:
                    collars, fixes = self._decode(inbox)
                    out = self.stream.push(collars, fixes, time.time())
                else:
                    out = self.stream.collect(time.time())
                self._publish(out)
            except Exception as exc:   # a bad batch must never stop the node
                self.message_errors += len(inbox)
                self.get_logger().warn(f'{len(inbox)} fixes dropped ({type(exc).__name__}: '
                                       f'{exc})', throttle_duration_sec=5.0)
        self._advance_diagnostics()

    def _decode(self, inbox):
        """Serialized fixes -> (collar indices, decoded fixes) of those that decode and name
        a collar (each of the others counted)."""
        fixes, bad = decode_navsatfixes([data for _, data in inbox])
        if bad:
            self.message_errors += len(bad)
            self.get_logger().warn(f'{len(bad)} fixes dropped: not a NavSatFix ({bad[0][1]})',
                                   throttle_duration_sec=5.0)
        m = len(fixes.stamp)
        if not self.cfg.fix_topic:
            skip = {k for k, _ in bad}
            return np.fromiter((c for k, (c, _) in enumerate(inbox) if k not in skip),
                               np.int64, m), fixes
        collars = np.fromiter((self._frames.get(f, -1) for f in fixes.frame_id), np.int64, m)
        for k in np.flatnonzero(collars < 0):   # a frame naming a collar once made a ROS name
            i = frame_collar(self._frames, fixes.frame_id[k])
            if i >= 0:
                self._frames[fixes.frame_id[k]] = i        # known from now on
                collars[k] = i
        unknown = np.flatnonzero(collars < 0)
        if not len(unknown):
            return collars, fixes
        self.unknown_collar_fixes += len(unknown)
        self.last_unknown_frame = fixes.frame_id[unknown[-1]]
        self.get_logger().warn(f'{len(unknown)} fixes on {self.cfg.fix_topic} name no collar '
                               f'of agents (frame_id {self.last_unknown_frame!r})',
                               throttle_duration_sec=5.0)
        return collars[collars >= 0], take_fixes(fixes, collars >= 0)

    def _publish(self, out):
        publish = self._odom_publish
        for idx, stamp, x, P in out.odometry:
            for i, data in zip(idx.tolist(), self._odom.encode(idx, stamp, x, P)):
                publish[i](data)
        for snap in out.snapshots:
            self.poses_pub.publish(encode_pose_array(snap.time, self.cfg.frame_id,
                                                     snap.positions))
        for level, text in out.log:
            if level == 'info':
                self.get_logger().info(text)
            elif text.startswith('data time jumped'):
                self.get_logger().warn(text)
            else:   # one throttled line per batch (a throttled call still costs ~1 ms)
                self.get_logger().warn(text, throttle_duration_sec=5.0)

    # -- diagnostics --------------------------------------------------------------------
    def publish_diagnostics(self):
        """Start the diagnostics of this period, published :data:`DIAGNOSTICS_STEP` collars
        per DiagnosticArray between batches (monitors key statuses by name, so several
        arrays per period are one report); the node's own status comes in the last one."""
        if self._diagnostics_job is not None:
            return                       # the previous one is still being built
        self._diagnostics_job = self._diagnostics()
        if self.cfg.batch_period_s == 0:
            self._advance_diagnostics(until_done=True)

    def _advance_diagnostics(self, until_done: bool = False):
        job = self._diagnostics_job
        try:
            while job is not None:
                next(job)
                if not until_done:
                    return
        except StopIteration:
            self._diagnostics_job = None

    def _diagnostics(self):
        stream, agents, statuses = self.stream, self.cfg.agents, []
        stale_all = stream.stale()
        n = len(agents)
        share = min(n, self.cfg.diagnostics_max_collars)
        first = self._diagnostics_next % n
        self._diagnostics_next = (first + share) % n
        for j in range(share):
            i = (first + j) % n
            if j and j % self.DIAGNOSTICS_STEP == 0:
                self.diag_pub.publish(diagnostic_array(self, statuses))
                statuses = []
                yield
            counters, previous = stream.counters(i), self._reported[i]
            rejected_now = any(counters[k] > previous.get(k, 0) for k in counters
                               if k.startswith('rejected_'))
            self._reported[i] = counters
            warn, message = stream.collar_status(i, bool(stale_all[i]), rejected_now)
            values = dict(counters, stale=bool(stale_all[i]), last_fix=float(stream.bank.t[i]),
                          last_rejection=stream.last_rejection[agents[i]])
            self._statuses[i] = refresh_status(self._statuses[i], f'gps_ingest: {agents[i]}',
                                               WARN if warn else OK, message, values,
                                               hardware_id=agents[i])
            statuses.append(self._statuses[i])
        errors = self.message_errors + stream.dropped_waiting
        new_bad = errors - self._errors_reported[0]
        new_unknown = self.unknown_collar_fixes - self._errors_reported[1]
        self._errors_reported = (errors, self.unknown_collar_fixes)
        problems = ([f'{new_bad} bad message{"s" * (new_bad > 1)} dropped'] if new_bad
                    else []) + ([f'{new_unknown} fix{"es" * (new_unknown > 1)} of unknown '
                                 f'collars dropped'] if new_unknown else [])
        values = dict(stream.totals(int(stale_all.sum())), message_errors=errors,
                      unknown_collar_fixes=self.unknown_collar_fixes,
                      last_unknown_frame=self.last_unknown_frame)
        statuses.append(diagnostic_status(
            'gps_ingest', WARN if problems else OK,
            ('; '.join(problems) + ' since the last report') if problems else
            f'{n} collars' + (f', statuses of {share} per period in turn' if share < n else ''),
            values))
        self.diag_pub.publish(diagnostic_array(self, statuses))


def main(args=None):
    """Run the node (``ros2 run herd_ros NODE``); exits with its status."""
    exit_process(run_node(GpsIngest, args=args))


if __name__ == '__main__':
    main()
