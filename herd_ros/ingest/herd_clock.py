"""One uniform clock of step ``dt`` for the whole herd, in data time (doc/formats.md, "Time").

Ticks are the integer multiples of ``dt`` in epoch seconds (``t_k = k·dt``), so the clock does
not depend on which collar spoke first, and a bag replayed at any rate gives the same ticks.
The first tick is the first multiple of ``dt`` at or after the first stamp seen.

The value of agent i at tick t is **causal**: the filter state after the last accepted fix
with stamp ≤ t (its :class:`StateTimeline` entry), predicted to t with the filter's
constant-velocity model (:func:`herd_ros.ingest.collar_filter.predict_state`). The agent is
*stale* at t when that fix is more than ``stale_after`` seconds older than t (or there is
none); a stale agent's position and velocity are **NaN** (missing), never an extrapolation
(doc/formats.md, "Time"): real collars go silent for hours or days, and a prediction carried
across such a gap drifts kilometres. Its covariance is kept (it says how uncertain the
prediction would be).

Two drivers give the same snapshots for the same fixes:

* offline, :func:`resample_timelines`: every agent's whole timeline at once, vectorized over
  the ticks and the agents (:func:`states_at`);
* streaming, :class:`HerdClock`: fed one fix at a time (after its filter has processed it),
  it emits the snapshot of tick t once every agent has reported (any fix, accepted or not)
  with a stamp ≥ t, or has been silent for more than ``stale_after`` seconds of herd data
  time (the latest stamp from any collar). Before its first report an agent counts as
  having reported at the first stamp of the herd, so the clock waits up to ``stale_after``
  for late starters. :meth:`HerdClock.flush` emits the remaining ticks at the end of data.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from herd_ros.ingest import collar_bank, collar_threads
from herd_ros.ingest.collar_filter import CollarFilter, predict_state
from herd_ros.trajectory import HerdTrajectory


def first_tick_index(t: float, dt: float) -> int:
    """Index k of the first tick ``k·dt`` at or after ``t``."""
    k = math.ceil(t / dt)
    # guard against t/dt rounding: k*dt must be >= t and (k-1)*dt < t
    if k * dt < t:
        k += 1
    elif (k - 1) * dt >= t:
        k -= 1
    return int(k)


def tick_grid(t_first: float, t_last: float, dt: float) -> np.ndarray:
    """The ticks ``k·dt`` with ``t_first ≤ k·dt ≤ t_last`` (s)."""
    k0 = first_tick_index(t_first, dt)
    k1 = first_tick_index(t_last, dt)
    if k1 * dt > t_last:
        k1 -= 1
    return np.arange(k0, k1 + 1, dtype=float) * dt


@dataclass
class StateTimeline:
    """The states of one collar filter after each accepted fix (or re-initialisation).

    Attributes:
        t: (K,) data times (s), increasing.
        x: (K, 4) states [e, n, ve, vn].
        P: (K, 4, 4) covariances.
        accel_std: the filter's process noise (m/s²), used to predict to the ticks.
        stale_after: the filter's staleness horizon (s).
        segment: (K,) int, which (re)initialisation each state descends from; consecutive
            states of one segment are one Kalman predict/update apart (what RTS needs).
        velocity_tau: the filter's velocity correlation time (s; 0 = constant velocity).
        motion: (K, 2) or None: per state, the motion model (σ_a, τ_v) that carries it
            forward (a collar whose model is refitted as its fixes arrive,
            :mod:`~herd_ros.ingest.motion_refit`); None = ``accel_std``, ``velocity_tau``
            for every state.
        walk: (σ_a, τ_v, π) of the filter's walk component (a graze/walk mixture,
            :attr:`~herd_ros.ingest.collar_filter.FilterParams.walk`, taken with prior
            probability π at every step), or None: what the smoothers predict with.
    """

    t: np.ndarray
    x: np.ndarray
    P: np.ndarray
    accel_std: float
    stale_after: float
    segment: np.ndarray | None = None
    velocity_tau: float = 0.0
    motion: np.ndarray | None = None
    walk: tuple | None = None

    def __post_init__(self):
        if self.segment is None:
            self.segment = np.zeros(len(self.t), dtype=int)

    def at(self, ticks):
        """Causal estimates at ``ticks`` (T,): (x (T, 4), P (T, 4, 4), stale (T,),
        initialised (T,)). Ticks before the first state give NaN, stale and not initialised.
        """
        x, P, stale, init = states_at([self], ticks)
        return x[0], P[0], stale[0], init[0]


def states_at(timelines, ticks, position_cov_only: bool = False):
    """:meth:`StateTimeline.at` of several timelines at the same ``ticks`` (T,): (x (N, T, 4),
    P (N, T, 4, 4), stale (N, T), initialised (N, T)); with ``position_cov_only`` P is the
    position block alone, (N, T, 2, 2). Each tick takes the timeline's state after its last
    accepted fix at or before it, predicted to the tick with that state's motion model; the
    predictions of every timeline are one compiled call over all of them that writes each
    where it goes (``predict_gathered``), split over the collar threads
    (:mod:`~herd_ros.ingest.collar_threads`: each state's prediction is its own, so the
    split never changes a number)."""
    ticks = np.asarray(ticks, dtype=float)
    N, T = len(timelines), len(ticks)
    x = np.full((N, T, 4), np.nan)
    P = np.full((N, T, 2, 2) if position_cov_only else (N, T, 4, 4), np.nan)
    stale = np.ones((N, T), bool)
    sizes = np.array([len(tl.t) for tl in timelines], dtype=np.int64)
    idx = np.full((N, T), -1, dtype=np.int64)
    for i, tl in enumerate(timelines):
        if sizes[i]:
            idx[i] = np.searchsorted(tl.t, ticks, side='right') - 1
    init = idx >= 0
    if not init.any():
        return x, P, stale, init
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    g = (idx + offsets[:, None])[init]                 # each (agent, tick)'s state
    t_all = _joined([np.asarray(tl.t, dtype=float) for tl in timelines])
    tau = np.broadcast_to(ticks, (N, T))[init] - t_all[g]
    x_all = _joined([np.asarray(tl.x, dtype=float).reshape(-1, 4) for tl in timelines])
    P_all = _joined([np.asarray(tl.P, dtype=float).reshape(-1, 4, 4) for tl in timelines])
    motion = _joined([
        np.column_stack([np.full(len(tl.t), float(tl.accel_std)),
                         np.full(len(tl.t), float(tl.velocity_tau))])
        if tl.motion is None else np.asarray(tl.motion, dtype=float).reshape(-1, 2)
        for tl in timelines])
    if collar_bank.AVAILABLE:
        # compiled: each state predicted and written to its (agent, tick) in one pass
        dest = np.flatnonzero(init.reshape(-1))
        x_all, P_all, motion = (np.ascontiguousarray(a, dtype=float)
                                for a in (x_all, P_all, motion))
        flat_x, flat_P = x.reshape(N * T, 4), P.reshape(N * T, *P.shape[2:])

        def part(sl):
            return lambda: collar_bank.KERNELS.predict_gathered(
                g[sl], dest[sl], tau[sl], x_all, P_all, motion, flat_x, flat_P)

        collar_threads.run(part(sl) for sl in collar_threads.split(np.ones(len(g))))
    else:                   # numpy: the states of each motion model together
        xs, Ps = np.empty((len(g), 4)), np.empty((len(g), 4, 4))
        models, which = np.unique(motion[g], axis=0, return_inverse=True)
        which = np.asarray(which).reshape(-1)
        for j, (accel, vt) in enumerate(models.tolist()):
            sel = which == j
            xs[sel], Ps[sel] = predict_state(x_all[g[sel]], P_all[g[sel]], tau[sel], accel,
                                             vt)
        x[init], P[init] = xs, (Ps[:, :2, :2] if position_cov_only else Ps)
    stale_after = np.array([float(tl.stale_after) for tl in timelines])
    stale[init] = tau > np.broadcast_to(stale_after[:, None], (N, T))[init]
    x[stale] = np.nan
    return x, P, stale, init


def _joined(arrays: list) -> np.ndarray:
    """The arrays one after the other (the one array itself, not a copy, when alone)."""
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


class TimelineRecorder:
    """Appends a filter's state to a growing timeline whenever it accepted a fix."""

    def __init__(self, collar_filter: CollarFilter):
        self.filter = collar_filter
        self._accepted = collar_filter.counters['accepted']
        self.t: list[float] = []
        self.x: list[np.ndarray] = []
        self.P: list[np.ndarray] = []
        self.segment: list[int] = []
        self.motion: list[tuple[float, float]] = []

    def record(self) -> bool:
        """Record the filter's state if it changed since the last call; True if it did."""
        accepted = self.filter.counters['accepted']
        if accepted == self._accepted:
            return False
        self._accepted = accepted
        self.t.append(self.filter.t)
        self.x.append(self.filter.x.copy())
        self.P.append(self.filter.P.copy())
        self.segment.append(self.filter.counters['reinitialised'])
        p = self.filter.params
        self.motion.append((p.accel_std, p.velocity_tau))
        return True

    def timeline(self) -> StateTimeline:
        """The collar's accepted states so far as a :class:`StateTimeline`."""
        p = self.filter.params
        return StateTimeline(np.asarray(self.t, dtype=float),
                             np.asarray(self.x, dtype=float).reshape(-1, 4),
                             np.asarray(self.P, dtype=float).reshape(-1, 4, 4),
                             p.accel_std, p.stale_after,
                             np.asarray(self.segment, dtype=int), p.velocity_tau,
                             np.asarray(self.motion, dtype=float).reshape(-1, 2),
                             walk_of(p))


def walk_of(params) -> tuple | None:
    """(σ_a, τ_v, π) of the walk component of a filter with ``params`` (a
    :class:`~herd_ros.ingest.collar_filter.FilterParams`), or None: a timeline's ``walk``."""
    w = params.walk
    return None if w is None else (float(w[0]), float(w[1]), float(params.walk_probability))


def resample_timelines(timelines: dict[str, StateTimeline], ticks, agents=None
                       ) -> HerdTrajectory:
    """Offline: every agent's causal estimate at every tick, as a :class:`HerdTrajectory`.

    ``meta`` holds ``velocities`` (T, N, 2) m/s, ``position_cov`` (T, N, 2, 2) m²,
    ``stale`` (T, N) and ``initialised`` (T, N) booleans. Positions of agents without any
    accepted fix at or before a tick are NaN.
    """
    agents = list(timelines) if agents is None else list(agents)
    ticks = np.asarray(ticks, dtype=float)
    x, P, stale, init = states_at([timelines[a] for a in agents], ticks,
                                  position_cov_only=True)
    x = x.swapaxes(0, 1)
    return HerdTrajectory(ticks, agents, x[..., :2].copy(), meta={
        'velocities': x[..., 2:].copy(),
        'position_cov': np.ascontiguousarray(P.swapaxes(0, 1)),
        'stale': stale.T.copy(), 'initialised': init.T.copy()})


@dataclass
class HerdSnapshot:
    """All agents at one tick of the herd clock (the content of ``/herd/poses``).

    Attributes:
        time: the tick (s, data time).
        agents: agent ids, in order.
        positions: (N, 2) m; NaN for a stale agent (or one never initialised).
        velocities: (N, 2) m/s; NaN where the position is.
        position_cov: (N, 2, 2) m².
        stale: (N,) no accepted fix within ``stale_after`` before the tick (position NaN).
        initialised: (N,) the agent has an accepted fix at or before the tick.
    """

    time: float
    agents: list[str]
    positions: np.ndarray
    velocities: np.ndarray
    position_cov: np.ndarray
    stale: np.ndarray
    initialised: np.ndarray


@dataclass
class _AgentRecords:
    recorder: TimelineRecorder
    reported: float = -math.inf       # latest stamp of any fix from this agent
    start: int = 0                    # first record that may still be needed


class HerdClock:
    """Streaming herd clock: feed fixes one at a time, collect the snapshots it completes.

    Usage (a node's fix callback)::

        result = filters[agent].update(stamp, e, n, ...)
        for snap in clock.observe(agent, stamp, filters[agent]):
            publish(snap)

    Args:
        agents: the agent ids, in snapshot order.
        dt: clock step (s).
        stale_after: seconds of herd data time after which a silent agent no longer holds
            the clock back (and after which an agent's estimate is flagged stale).
    """

    def __init__(self, agents, dt: float, stale_after: float):
        if not dt > 0:
            raise ValueError(f'dt must be positive, got {dt!r}')
        self.agents = list(agents)
        self.dt = float(dt)
        self.stale_after = float(stale_after)
        self._agents: dict[str, _AgentRecords] = {}
        self.herd_time = -math.inf
        self._next_k: int | None = None

    @property
    def next_tick(self) -> float | None:
        """The next tick to be emitted (None before the first fix)."""
        return None if self._next_k is None else self._next_k * self.dt

    def observe(self, agent: str, stamp: float, collar_filter: CollarFilter
                ) -> list[HerdSnapshot]:
        """Take note of one fix of ``agent`` (accepted or rejected), already processed by
        ``collar_filter``; return the snapshots completed by it (oldest first)."""
        if agent not in self.agents:
            raise KeyError(f'unknown agent {agent!r}')
        rec = self._agents.get(agent)
        if rec is None or rec.recorder.filter is not collar_filter:
            rec = self._agents[agent] = _AgentRecords(TimelineRecorder(collar_filter),
                                                      rec.reported if rec else -math.inf)
            if collar_filter.initialised:   # a filter that ran before it was registered
                rec.recorder._accepted = -1
        rec.recorder.record()
        stamp = float(stamp)
        if not math.isfinite(stamp):
            return []
        if self._next_k is None:
            self._next_k = first_tick_index(stamp, self.dt)
            self._first_stamp = stamp
        rec.reported = max(rec.reported, stamp)
        self.herd_time = max(self.herd_time, stamp)
        return self._emit(final=False)

    def flush(self) -> list[HerdSnapshot]:
        """End of data: emit every remaining tick up to the latest stamp seen."""
        return self._emit(final=True)

    # -- internals ------------------------------------------------------------------------
    def _ready(self, tick: float) -> bool:
        if tick > self.herd_time:
            return False
        for agent in self.agents:
            rec = self._agents.get(agent)
            reported = rec.reported if rec is not None else -math.inf
            if reported >= tick:
                continue
            silent = self.herd_time - max(reported, self._first_stamp) > self.stale_after
            if not (silent and tick < self.herd_time):
                return False
        return True

    def _emit(self, final: bool) -> list[HerdSnapshot]:
        out = []
        if self._next_k is None:
            return out
        while True:
            tick = self._next_k * self.dt
            if tick > self.herd_time or not (final or self._ready(tick)):
                break
            out.append(self._snapshot(tick))
            self._next_k += 1
        return out

    def _snapshot(self, tick: float) -> HerdSnapshot:
        N = len(self.agents)
        x = np.full((N, 4), np.nan)
        P = np.full((N, 4, 4), np.nan)
        stale = np.ones(N, bool)
        init = np.zeros(N, bool)
        for i, agent in enumerate(self.agents):
            rec = self._agents.get(agent)
            if rec is None:
                continue
            r = rec.recorder
            # drop records superseded by a later one still at or before this tick
            while rec.start + 1 < len(r.t) and r.t[rec.start + 1] <= tick:
                rec.start += 1
            if rec.start >= 32:    # keep the lists short on long runs (amortised O(1);
                # with 1024 a live collar held up to 1024 records: ~0.5 GB for 1000 collars
                # at 1 Hz, growing for 17 minutes -- measured by test/bench/bench_soak.py)
                del r.t[:rec.start], r.x[:rec.start], r.P[:rec.start], r.segment[:rec.start]
                rec.start = 0
            if rec.start < len(r.t) and r.t[rec.start] <= tick:
                p = r.filter.params
                tau = tick - r.t[rec.start]
                x[i], P[i] = predict_state(r.x[rec.start], r.P[rec.start], tau, p.accel_std,
                                           p.velocity_tau)
                init[i] = True
                stale[i] = tau > p.stale_after
                if stale[i]:
                    x[i] = np.nan
        return HerdSnapshot(tick, list(self.agents), x[:, :2].copy(), x[:, 2:].copy(),
                            P[:, :2, :2].copy(), stale, init)


def _per_collar(value, n: int) -> np.ndarray:
    """``value`` itself if it is a float (n,) array (shared, not copied), else a new one."""
    if isinstance(value, np.ndarray) and value.shape == (n,) and value.dtype == float:
        return value
    return np.full(n, float(value))


class BatchHerdClock:
    """The streaming herd clock of a :class:`~herd_ros.ingest.collar_bank.CollarBank`,
    fed a batch of fixes at a time (the ``gps_ingest`` node); O(collars) compiled work per
    tick instead of a Python loop over the collars.

    The rules are those of :class:`HerdClock` (module docstring): tick t is emitted once
    every collar has reported (any fix) at or after t, or has been silent for more than
    ``stale_after`` seconds of herd data time; a collar's value at t is its state after the
    last accepted fix at or before t, predicted to t, NaN when stale. Readiness is checked
    after each batch rather than after each fix, so a fix that arrives in the same batch
    as the fixes completing a tick is already known when the tick is emitted (as offline).

    Each collar keeps the accepted states the clock may still need in a small ring
    (states superseded for the next tick are dropped; the ring doubles if a collar runs
    far ahead of a lagging one).

    Args:
        agents: collar ids in snapshot order (index i = the bank's collar i).
        dt: clock step (s).
        stale_after: staleness horizon (s).
        accel_std, velocity_tau: the motion model that carries states to the ticks: one for
            all, or per collar ((n,) arrays; the node passes its bank's own arrays, so a
            refitted collar model reaches the clock at once).
        grace_s: wall time (s) a collar must also have sent nothing for before it counts as
            silent (0: data time alone decides, as offline). Data time alone cannot tell a
            silent collar from one whose fixes are still queued: when a busy machine works
            off a backlog one message per topic in turn, a collar that reports every 5 s
            runs ahead in data time of those that report every second, and the herd time
            (the latest stamp) with it; without the grace every other collar looked silent
            and was NaN in every pose (a replay of the baboons at 30 × real time on a
            2-core machine: one or two of 19 animals per pose). With it, a collar whose
            fixes are still arriving is waited for; one that went quiet is silent a
            ``grace_s`` of wall time later (:meth:`poll`).
    """

    def __init__(self, agents, dt: float, stale_after: float, accel_std,
                 velocity_tau=0.0, depth: int = 8, grace_s: float = 0.0):
        if not dt > 0:
            raise ValueError(f'dt must be positive, got {dt!r}')
        self.agents = list(agents)
        n = len(self.agents)
        self.dt = float(dt)
        self.stale_after = float(stale_after)
        self.accel_std = _per_collar(accel_std, n)
        self.velocity_tau = _per_collar(velocity_tau, n)
        self.reported = np.full(n, -np.inf)
        self.grace_s = float(grace_s)
        self.received = np.full(n, -np.inf)     # wall time of each collar's latest fix
        self.waiting = np.zeros(n, bool)        # fixes arrived, not yet filtered: not silent
        self.now = -math.inf                    # wall time of the latest batch or poll
        self.herd_time = -math.inf
        self._next_k: int | None = None
        self._first_stamp = -math.inf
        self.count = np.zeros(n, np.int64)
        self.rt = np.full((n, depth), np.nan)
        self.rx = np.zeros((n, depth, 4))
        self.rP = np.zeros((n, depth, 4, 4))
        self.rm = np.zeros((n, depth, 2))

    @property
    def next_tick(self) -> float | None:
        """The next tick the clock will publish (s), or None before the first fix."""
        return None if self._next_k is None else self._next_k * self.dt

    def observe(self, collar, stamp, accepted, x, P, motion=None,
                now: float | None = None) -> list[HerdSnapshot]:
        """Take note of a batch of fixes (all of them, accepted or not, in arrival order)
        after the bank processed it: ``collar`` (M,), ``stamp`` (M,), ``accepted`` (M,)
        and the states after the accepted ones ``x`` (M, 4), ``P`` (M, 4, 4), with the
        motion model (σ_a, τ_v) that carries each forward, ``motion`` (M, 2) (None: this
        clock's ``accel_std``, ``velocity_tau`` of the collar), received at wall time
        ``now`` (s; for ``grace_s``). Returns the snapshots completed (oldest first)."""
        collar = np.asarray(collar, dtype=np.int64)
        stamp = np.asarray(stamp, dtype=float)
        if now is not None:
            self.now = max(self.now, float(now))
            self.received[collar] = self.now
        finite = np.isfinite(stamp)
        if not finite.any():
            return []
        if self._next_k is None:
            first = float(stamp[np.argmax(finite)])
            self._next_k = first_tick_index(first, self.dt)
            self._first_stamp = first
        keep = np.asarray(accepted, bool) & finite
        rows = np.flatnonzero(keep)
        if motion is None:
            motion = np.column_stack([self.accel_std[collar], self.velocity_tau[collar]])
        while len(rows):
            done = collar_bank.KERNELS.record_states(
                collar[rows], stamp[rows], np.ascontiguousarray(x[rows]),
                np.ascontiguousarray(P[rows]), np.ascontiguousarray(motion[rows], dtype=float),
                self.next_tick, self.count, self.rt, self.rx, self.rP, self.rm)
            if done == len(rows):
                break
            self._grow()
            rows = rows[done:]
        np.maximum.at(self.reported, collar[finite], stamp[finite])
        self.herd_time = max(self.herd_time, float(stamp[finite].max()))
        return self._emit(final=False)

    def flush(self) -> list[HerdSnapshot]:
        """End of data: emit every remaining tick up to the latest stamp seen."""
        return self._emit(final=True)

    def poll(self, now: float) -> list[HerdSnapshot]:
        """No new fix, wall time ``now`` (s): the ticks that waited only for the grace of a
        collar gone quiet (``grace_s``), now completed."""
        self.now = max(self.now, float(now))
        if self._next_k is None:
            return []
        return self._emit(final=False)

    @staticmethod
    def warm_up():
        """Load the compiled kernels (from numba's cache: ~0.3 s the first time in a process;
        instant when compiled ahead of time) so that the first fixes of a live node do
        not wait for it."""
        clock = BatchHerdClock(['warm-up'], 1.0, 1.0, 0.1)
        clock.observe(np.zeros(1, np.int64), np.zeros(1), np.ones(1, bool), np.zeros((1, 4)),
                      np.eye(4)[None])
        clock.snapshot(0.0)

    def _grow(self):
        n, depth = self.rt.shape
        rt = np.full((n, 2 * depth), np.nan)
        rx = np.zeros((n, 2 * depth, 4))
        rP = np.zeros((n, 2 * depth, 4, 4))
        rm = np.zeros((n, 2 * depth, 2))
        rt[:, :depth], rx[:, :depth], rP[:, :depth] = self.rt, self.rx, self.rP
        rm[:, :depth] = self.rm
        self.rt, self.rx, self.rP, self.rm = rt, rx, rP, rm

    def _ready(self, tick: float) -> bool:
        if tick > self.herd_time:
            return False
        silent = (self.herd_time - np.maximum(self.reported, self._first_stamp)
                  > self.stale_after)
        if self.grace_s > 0:
            silent &= self.now - self.received >= self.grace_s
        silent &= ~self.waiting
        return bool(np.all((self.reported >= tick) | (silent & (tick < self.herd_time))))

    _emit = HerdClock._emit     # the same tick loop over this class' _ready and _snapshot

    def snapshot(self, tick: float) -> HerdSnapshot:
        """Every collar at ``tick`` from the states kept (see the class docstring)."""
        n = len(self.agents)
        x = np.empty((n, 4))
        P = np.empty((n, 4, 4))
        stale = np.empty(n, np.bool_)
        init = np.empty(n, np.bool_)
        collar_bank.KERNELS.snapshot(float(tick), self.count, self.rt, self.rx, self.rP,
                                     self.rm, self.stale_after, x, P, stale, init)
        return HerdSnapshot(float(tick), list(self.agents), x[:, :2].copy(), x[:, 2:].copy(),
                            P[:, :2, :2].copy(), stale, init)

    _snapshot = snapshot
