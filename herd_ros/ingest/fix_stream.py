"""A stream of collar fixes -> filtered states and herd snapshots: the core of the
``gps_ingest`` node (issue 26), with no ROS in it.

:class:`FixStream` takes fixes a batch at a time (:meth:`FixStream.push`, any collars, in
arrival order) and keeps everything the node used to hold itself:

* **the datum**: given, or the offline rule (:func:`~herd_ros.ingest.pipeline.choose_datum`,
  the earliest-stamped valid fix), applied once every collar has sent a valid fix or
  ``stale_after`` s of data time have passed since the first valid one; fixes are held until
  then and released in stamp order, so the datum does not depend on arrival order and a
  NO_FIX or NaN fix never becomes it;
* **the stamp guard**: a fix stamped more than ``max_stamp_ahead_s`` ahead of ``now`` (the
  caller's wall clock) is rejected as ``future`` (:mod:`~herd_ros.ingest.stamp_guards`,
  which the offline path applies to a file with the time of the run);
* **the filters**: the compiled :class:`~herd_ros.ingest.collar_bank.CollarBank`, with the
  per-collar motion refits of :func:`~herd_ros.ingest.motion_refit.process_with_refits` when
  ``refit`` is given — the offline path's numerics;
* **the herd clock** (:class:`~herd_ros.ingest.herd_clock.BatchHerdClock`, data time): a
  forward jump of data time beyond ``max_clock_jump_s`` restarts it at the new time instead
  of emitting every tick of the gap (offline: the clock spans the accepted fixes, and a
  gap too long for one clock is a clear error);
* the bookkeeping diagnostics report: why each collar's last fix was refused, counts of
  future stamps, restarts and ticks.

Fed the same fixes in stamp order, the stream emits the snapshots of
``trajectory_from_fixes(..., smoother='none', trim=False)`` (``test_gps_ingest_node``).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd

from herd_ros.errors import HerdInputError
from herd_ros.ingest.collar_bank import OUTCOMES, CollarBank, FixBatch
from herd_ros.ingest.collar_filter import COUNTERS, STATUS_NO_FIX, FilterParams
from herd_ros.ingest.geodesy import geodetic_to_enu
from herd_ros.ingest.herd_clock import BatchHerdClock
from herd_ros.ingest.motion_refit import (BackgroundRefits, MotionRefitter, fix_variance,
                                          process_deferring, process_with_refits)
from herd_ros.ingest.pipeline import choose_datum, with_walk
from herd_ros.ingest.stamp_guards import clock_jumps, future_stamps
from herd_ros.io.cdr import NavSatFixes, concat_fixes, no_fixes, take_fixes

#: what a rejection means, for diagnostics and logs
REJECTION_TEXT = {
    'no_fix': 'status is STATUS_NO_FIX',
    'nan': 'latitude or longitude is not finite',
    'time': 'stamp not after the last fix (time going backwards, or a duplicate)',
    'speed': 'beyond reach of the track (max_speed, cruise_speed, sprint_s): an outlier '
             'unless more follow',
    'gate': 'outside the Mahalanobis gate',
    'range': 'far outside the range its collar has kept (range_sigmas, range_margin): an '
             'outlier unless reacquire_fixes follow',
    'unconfirmed': 'track lost or not started: waiting for consistent fixes',
}


@dataclasses.dataclass
class StreamOutput:
    """What one :meth:`FixStream.push` produced: the accepted fixes' states, in order, as
    (collars, stamps, x (M, 4), P (M, 4, 4)) per filtered batch; the herd snapshots
    completed; and log lines (level ``'info'`` or ``'warn'``, text)."""

    odometry: list = dataclasses.field(default_factory=list)
    snapshots: list = dataclasses.field(default_factory=list)
    log: list = dataclasses.field(default_factory=list)


class FixStream:
    """The ingest of a live stream of fixes (see the module docstring).

    Args:
        agents: collar ids (index = collar number in :meth:`push`).
        dt: herd clock step (s of data time).
        params: the filter's :class:`FilterParams` (with ``refit``: the prior and walk
            component, :func:`~herd_ros.ingest.pipeline.with_walk`).
        refit: a :class:`~herd_ros.ingest.motion_refit.RefitConfig`, or None (fixed model).
        datum: (lat, lon, alt) or None for the first valid fix.
        max_stamp_ahead_s, max_clock_jump_s: the two guards (s).
        silence_grace_s: wall time (s) a collar must also have sent nothing for before the
            herd clock counts it as silent (:class:`BatchHerdClock`'s ``grace_s``).
        refit_in_background: run the refits in a worker thread
            (:class:`~herd_ros.ingest.motion_refit.BackgroundRefits`; the same states,
            a collar's fixes wait only for its own refit): then :meth:`collect` must be
            called now and then (the node's batch timer) and with ``wait`` at the end.
    """

    def __init__(self, agents, dt: float, params: FilterParams, refit=None, datum=None,
                 max_stamp_ahead_s: float = math.inf, max_clock_jump_s: float = math.inf,
                 silence_grace_s: float = 0.0, refit_in_background: bool = False):
        self.agents, self.dt, self.params = list(agents), float(dt), params
        self.silence_grace_s = float(silence_grace_s)
        self.max_stamp_ahead_s, self.max_clock_jump_s = max_stamp_ahead_s, max_clock_jump_s
        self.bank = CollarBank(len(self.agents), params)
        self.refitter = MotionRefitter(len(self.agents), refit) if refit is not None else None
        self.background = (BackgroundRefits(self.bank, self.refitter)
                           if self.refitter is not None and refit_in_background else None)
        self._held: list[tuple] = []    # fixes waiting for their collar's refit (arrays)
        self.clock = self._new_clock()
        self.datum = datum
        self._pending: list[tuple] = []             # (collars, NavSatFixes) held for the datum
        self._pending_valid: dict[int, float] = {}  # collar -> first valid stamp held
        self._pending_latest = -math.inf
        self.rejected_future = dict.fromkeys(self.agents, 0)
        self.last_rejection = dict.fromkeys(self.agents, '')
        self.dropped_waiting = 0      # fixes dropped while no valid fix had come (memory)
        self.clock_restarts = 0
        self.ticks = 0

    @staticmethod
    def warm_up():
        """Load the compiled code before the first fix."""
        CollarBank.warm_up()
        BatchHerdClock.warm_up()

    def _new_clock(self) -> BatchHerdClock:
        return BatchHerdClock(self.agents, self.dt, self.params.stale_after,
                              self.bank.accel_std, self.bank.velocity_tau,
                              grace_s=self.silence_grace_s)

    @property
    def fixes_waiting_for_datum(self) -> int:
        """Fixes held until the datum is chosen."""
        return sum(len(c) for c, _ in self._pending)

    # -- live parameters (accel_std, walk_accel_std, max_speed, cruise_speed, sprint_s) --
    def _changed(self, name, value) -> FilterParams:
        if name == 'walk_accel_std':
            if self.refitter is None:       # a fixed model has no walk component
                return self.params
            # fitted collars: the walk component's (and the prior's) acceleration
            p = dataclasses.replace(self.params, walk_accel_std=None, walk_velocity_tau=None,
                                    velocity_tau=self.params.walk[1])
            return with_walk(p, float(value))
        if name == 'accel_std' and self.refitter is not None:
            return self.params              # the fixed model's, not used by fitted collars
        return dataclasses.replace(self.params, **{name: float(value)})

    def check_param(self, name, value) -> str | None:
        """Why the filter cannot take ``name = value`` (None = it can)."""
        try:
            self._changed(name, value)
        except HerdInputError as exc:
            return str(exc)
        return None

    def set_param(self, name, value):
        """The bank reads its parameters at every batch: the next fix uses the new value."""
        self.params = self.bank.params = self._changed(name, value)
        if name == 'accel_std' and self.refitter is None:
            self.bank.accel_std[:] = self.params.accel_std
        elif name == 'walk_accel_std' and self.refitter is not None:
            # the collars not fitted yet move by the new prior; the fits use the new walk
            unfitted = np.array([f is None for f in self.refitter.fits])
            self.bank.accel_std[unfitted] = self.params.accel_std
            w = self.params.walk
            self.refitter.config.walk = (w[0], w[1], self.params.walk_probability,
                                         self.refitter.config.walk[3])

    # -- fixes ------------------------------------------------------------------------
    def push(self, collars: np.ndarray, fixes: NavSatFixes, now: float) -> StreamOutput:
        """Fixes of ``collars`` (arrival order), received at wall time ``now``."""
        out = self.collect(now) if self.background is not None else StreamOutput()
        future = np.flatnonzero(future_stamps(fixes.stamp, now, self.max_stamp_ahead_s))
        if len(future):
            for k in future.tolist():
                agent = self.agents[collars[k]]
                self.rejected_future[agent] += 1
                self.last_rejection[agent] = (f'future: stamp {fixes.stamp[k]:.3f} is more '
                                              f'than max_stamp_ahead_s ahead of the wall clock')
            keep = np.ones(len(collars), bool)
            keep[future] = False
            collars, fixes = collars[keep], take_fixes(fixes, keep)
        if self.datum is None and len(collars):
            collars, fixes = self._hold(collars, fixes, out)
        if len(collars):
            self._filter(collars, fixes, out, now)
        return out

    def poll(self, now: float) -> StreamOutput:
        """No fix since the last :meth:`push`, wall time ``now``: the herd snapshots that
        waited only for a quiet collar's ``silence_grace_s`` (and the fixes that waited for
        a refit now finished)."""
        out = self.collect(now) if self.background is not None else StreamOutput()
        if self.silence_grace_s > 0:
            snaps = self.clock.poll(now)
            out.snapshots.extend(snaps)
            self.ticks += len(snaps)
        return out

    def _filter(self, idx: np.ndarray, fixes: NavSatFixes, out: StreamOutput,
                now: float | None = None):
        stamp = fixes.stamp
        lat0, lon0, alt0 = self.datum
        with np.errstate(invalid='ignore'):
            e, n, _ = geodetic_to_enu(fixes.lat, fixes.lon, fixes.alt, lat0, lon0, alt0,
                                      nan_alt=alt0)
        if self.refitter is None:
            batch = self.bank.process(idx, stamp, e, n, fixes.status,
                                      self.bank.measurement_covariances(fixes.cov_type,
                                                                        fixes.cov, idx))
            self._outcomes(idx, stamp, batch, None, out, now)
            return
        var = fix_variance(fixes.cov_type, fixes.cov[:, 0], fixes.cov[:, 4],
                           self.params.position_std_floor)
        rows = (idx, stamp, e, n, fixes.status, fixes.cov_type, fixes.cov, var)
        if self.background is not None:
            self._filter_deferring(rows, out, now)
            return
        batch, motion = process_with_refits(self.bank, self.refitter, *rows)
        self._outcomes(idx, stamp, batch, motion, out, now)

    # -- refits in the background -------------------------------------------------------
    def collect(self, now: float, wait: bool = False) -> StreamOutput:
        """The refits finished since the last call (every one with ``wait``: the end of
        data) ready to take over, and the fixes that waited for them filtered."""
        out = StreamOutput()
        refits = self.background
        if refits is None:
            return out
        while True:
            failures = refits.failures
            freed = refits.finish(wait)
            if refits.failures > failures:
                out.log.append(('warn', f'a motion refit failed ({refits.last_failure}): '
                                        f'its collars keep their models'))
            if not self._held or not (freed or wait):
                break
            held = _concat_rows(self._held)
            self._held = []
            self._filter_deferring(held, out, now)
            if not wait or not (self._held or refits.busy):
                break
        return out

    @property
    def refits_unfinished(self) -> bool:
        """Whether refits run in the background or fixes wait for them."""
        return self.background is not None and (bool(self._held) or self.background.busy)

    @property
    def fixes_held_for_refits(self) -> int:
        """Fixes waiting for their collar's refit (``refit_in_background``)."""
        return sum(len(r[0]) for r in self._held)

    def _filter_deferring(self, rows, out: StreamOutput, now):
        """:meth:`_filter` with the refits in the background
        (:func:`~herd_ros.ingest.motion_refit.process_deferring`): a fix that needs a model
        still being fitted waits for it (:meth:`collect`), with its collar's later fixes;
        the others are filtered now."""
        behind = np.zeros(len(self.agents), bool)       # collars with fixes waiting already
        for r in self._held:
            behind[r[0]] = True
        wait = behind[rows[0]]
        if wait.any():
            self._held.append(_take_rows(rows, wait))
            rows = _take_rows(rows, ~wait)
        self.clock.waiting[:] = behind                  # not silent: their fixes are here
        if len(rows[0]):
            batch, motion, held = process_deferring(self.bank, self.refitter,
                                                    self.background, rows)
            if held.any():
                self._held.append(_take_rows(rows, held))
                self.clock.waiting[rows[0][held]] = True
            done = np.flatnonzero(~held)
            self._outcomes(rows[0][done], rows[1][done], _batch_rows(batch, done),
                           motion[done], out, now)
        self.clock.waiting[:] = False
        for r in self._held:
            self.clock.waiting[r[0]] = True

    def _outcomes(self, idx, stamp, batch, motion, out: StreamOutput, now):
        """Odometry, rejections and herd snapshots of a filtered batch."""
        accepted = batch.accepted
        done = np.flatnonzero(accepted)
        out.odometry.append((idx[done], stamp[done], batch.x[done], batch.P[done]))
        rejected = np.flatnonzero(~accepted).tolist()
        for k in rejected:
            agent, reason = self.agents[idx[k]], OUTCOMES[batch.outcome[k]]
            detail = REJECTION_TEXT[reason]
            if reason == 'gate':
                detail += f' (distance² {batch.mahalanobis2[k]:.1f})'
            self.last_rejection[agent] = f'{reason}: {detail}'
        if rejected:
            k = rejected[0]
            agent = self.agents[idx[k]]
            more = f' (and {len(rejected) - 1} more in this batch)' if len(rejected) > 1 else ''
            out.log.append(('warn', f'{agent}: fix at {stamp[k]:.3f} rejected '
                                    f'({self.last_rejection[agent]}){more}'))
        jumps, before = clock_jumps(self.clock.herd_time, stamp, self.max_clock_jump_s)
        start, m = 0, len(idx)
        for j in jumps + [m]:
            if j > start:
                sl = slice(start, j)
                snaps = self.clock.observe(idx[sl], stamp[sl], accepted[sl], batch.x[sl],
                                           batch.P[sl], None if motion is None else motion[sl],
                                           now=now)
                out.snapshots.extend(snaps)
                self.ticks += len(snaps)
            if j < m:
                self.clock_restarts += 1
                out.log.append(('warn', f'data time jumped {stamp[j] - before[j]:.0f} s '
                                        f'(> max_clock_jump_s): herd clock restarted at '
                                        f'{stamp[j]:.3f}'))
                waiting = self.clock.waiting
                self.clock = self._new_clock()
                self.clock.waiting[:] = waiting
                start = j

    # -- datum from the first valid fix -----------------------------------------------
    def _hold(self, collars: np.ndarray, fixes: NavSatFixes, out: StreamOutput):
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
            held = self.fixes_waiting_for_datum
            while held > 100 * len(self.agents) and len(self._pending) > 1:
                dropped = len(self._pending.pop(0)[0])   # nothing valid yet: bound memory
                self.dropped_waiting += dropped
                held -= dropped
            return nothing
        everyone = len(self._pending_valid) == len(self.agents)
        waited = (self._pending_latest - min(self._pending_valid.values())
                  > self.params.stale_after)
        if not (everyone or waited):
            return nothing
        collars = np.concatenate([c for c, _ in self._pending])
        held = concat_fixes([f for _, f in self._pending])
        table = pd.DataFrame({'time': held.stamp,
                              'agent': [self.agents[i] for i in collars.tolist()],
                              'lat': held.lat, 'lon': held.lon, 'alt': held.alt,
                              'status': held.status})
        self.datum = choose_datum(table)
        out.log.append(('info', datum_text(self.datum, 'first valid fix')))
        self._pending = []
        order = np.argsort(held.stamp, kind='stable')
        return collars[order], take_fixes(held, order)

    # -- diagnostics ------------------------------------------------------------------
    def stale(self) -> np.ndarray:
        """Which collars are stale at the herd clock's time."""
        t = self.clock.herd_time
        return self.bank.is_stale(t) if math.isfinite(t) else np.zeros(len(self.agents), bool)

    def counters(self, i: int) -> dict:
        """Collar ``i``'s outcome counters (:data:`COUNTERS` and ``rejected_future``)."""
        c = self.bank.counter_dict(i)
        c['rejected_future'] = self.rejected_future[self.agents[i]]
        return c

    def collar_status(self, i: int, stale: bool, rejected_now: bool) -> tuple[bool, str]:
        """(warn, message) of collar ``i``: a rejection since the last report, or stale."""
        if rejected_now:
            return True, f'rejected {self.last_rejection[self.agents[i]]}'
        if stale:
            return True, ('stale: no accepted fix yet' if not self.bank.initialised[i] else
                          f'stale: silent for more than {self.params.stale_after:g} s, '
                          f'missing (NaN) in /herd/poses')
        return False, 'ok'

    def totals(self, stale_count: int) -> dict:
        """The node-level values of diagnostics."""
        totals = self.bank.counters.sum(axis=0)
        return {'herd_time': self.clock.herd_time, 'ticks_published': self.ticks,
                'fixes': int(totals[:-1].sum()) + sum(self.rejected_future.values()),
                'accepted': int(totals[0]), 'stale_collars': stale_count,
                'clock_restarts': self.clock_restarts,
                'refits_in_flight': (self.background.in_flight if self.background is not None
                                     else 0),
                'fixes_held_for_refits': self.fixes_held_for_refits,
                'fixes_waiting_for_datum': self.fixes_waiting_for_datum,
                'datum': ('waiting for the first valid fix' if self.datum is None
                          else ', '.join(f'{v:.9f}' for v in self.datum))}


def _batch_rows(batch: FixBatch, keep) -> FixBatch:
    """The rows ``keep`` (indices) of a filtered batch."""
    return FixBatch(batch.outcome[keep], batch.mahalanobis2[keep], batch.x[keep],
                    batch.P[keep], batch.segment[keep])


def _take_rows(rows: tuple, keep) -> tuple:
    """The rows ``keep`` (mask or indices) of a tuple of per-fix arrays."""
    return tuple(a[keep] for a in rows)


def _concat_rows(parts: list) -> tuple:
    """Tuples of per-fix arrays, one after the other."""
    return tuple(np.concatenate(cols) for cols in zip(*parts))


def collar_frames(agents) -> dict:
    """header.frame_id -> collar index on a shared fix topic: ``<agent>`` and the sensor
    frames ``<agent>_gps`` (what ``herd-ros import`` writes) and ``<agent>/gps``."""
    frames = {}
    for i, agent in enumerate(agents):
        for frame in (agent, f'{agent}_gps', f'{agent}/gps'):
            frames.setdefault(frame, i)
    return frames


def frame_collar(frames: dict, frame: str) -> int:
    """The collar of a ``header.frame_id`` that names it only once made a ROS name, as the
    file readers make ids (:func:`herd_ros.agent_ids.ros_agent_id`): ``4262-8483``,
    ``4262-8483_gps`` or ``4262-8483/gps`` for the agent ``id_4262_8483``; -1 if none
    (``frames``: :func:`collar_frames`)."""
    from herd_ros.agent_ids import ros_agent_id
    base = str(frame)
    for suffix in ('/gps', '_gps'):
        if base.endswith(suffix):
            base = base[:-len(suffix)]
            break
    return frames.get(ros_agent_id(base), -1) if base.strip() else -1


def datum_text(datum, source: str) -> str:
    """The one line that says which datum is used."""
    return 'datum (%s): lat %.9f lon %.9f alt %.3f' % ((source,) + tuple(datum))


__all__ = ['COUNTERS', 'FixStream', 'REJECTION_TEXT', 'StreamOutput', 'clock_jumps',
           'collar_frames', 'datum_text', 'frame_collar', 'future_stamps']
