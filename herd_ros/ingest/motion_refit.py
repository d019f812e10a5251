"""Each collar's motion model refitted as its fixes arrive: the same causal schedule live
and offline.

A collar starts with a prior that follows its fixes (a random walk with the configured
model's diffusion, :func:`herd_ros.ingest.pipeline.with_walk`). Right after its n-th fix
(any outcome) for n in :func:`refit_due`'s schedule — 20, 40, 80, ..., doubling up to
``max_interval`` fixes
apart, then every ``max_interval`` fixes — its model is refitted by maximum likelihood
(:func:`herd_ros.ingest.motion_fit.fit_motion`, warm-started from its previous fit) on its
last ``window`` accepted fixes. The new model filters the collar's fixes from its first
fix after the n-th that is stamped at least ``lag_s`` seconds of data time after it
(:class:`RefitConfig`; with ``lag_s`` 0, from its next fix). The fit only ever sees fixes
the filter already had, so the track stays causal, and since a collar's fit depends on its
own fixes alone and takes over at a point fixed by the stamps, the ``gps_ingest`` node
(fixes in arrival order, in batches) and ``herd-ros ingest`` (a whole file at once) refit
at the same fixes and give the same states.

**Why a lag.** Live, the refits run in a worker thread while the fixes go on being
filtered (:class:`BackgroundRefits`), but a fix that must be filtered by a model still
being fitted has to wait for it. A herd of collars switched on together reaches its 20th
fix together: 10 000 collars at 1 Hz refit at once, 2-5 s of work on two cores (more for
the later, longer windows), and with the model needed at the next fix every collar's
fixes waited for it — fix-to-odometry latency up to 1.1 s every few tens of seconds
(``test/bench/bench_ingest_dds.py``: p99 150-565 ms against 7.6 ms with no refits). With
the new model taking over ``lag_s`` later, the fit has that long to finish before any fix
needs it; a fix waits only when a refit takes longer than the lag.

:func:`process_with_refits` drives a :class:`~herd_ros.ingest.collar_bank.CollarBank`
through a batch: it splits the batch only where a refit must be fitted before a collar's
next fix (its window as it is at its refit point) or a fitted model must take over before
one (:func:`stabbing_cuts`), so refits due together are fitted together (one vectorised
call); :func:`process_deferring` is the same with the fits in the background.

Plain numpy; no ROS.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from herd_ros.ingest.collar_bank import FixBatch
from herd_ros.ingest.motion_fit import MotionFit, fit_motion

#: first refit (fixes), the schedule doubles from here
FIRST_REFIT = 20
#: the default lag per collar of the herd (s): what a refit of every collar may take on a
#: small machine (one core, the fix path beside it: 0.5-4.5 ms a collar for 20- to 200-fix
#: windows), so 60 s for 10 000 collars, 0.1 s for 19 (the next fix of a 1 Hz collar)
REFIT_LAG_PER_COLLAR_S = 0.006


def refit_lag(collars: int, lag_s: float | None = None) -> float:
    """The refits' lag (s): ``lag_s`` when given (≥ 0), else (None or negative: auto)
    :data:`REFIT_LAG_PER_COLLAR_S` per collar of the herd (module docstring)."""
    if lag_s is not None and lag_s >= 0:
        return float(lag_s)
    return REFIT_LAG_PER_COLLAR_S * max(int(collars), 1)


def refit_due(count, first: int = FIRST_REFIT, max_interval: int = 1000) -> np.ndarray:
    """Whether a collar's model is refitted right after its ``count``-th fix (array):
    ``first · 2^k`` while the step is below ``max_interval``, then every ``max_interval``."""
    n = np.asarray(count, dtype=np.int64)
    due = np.zeros(n.shape, bool)
    g = first
    while g < max_interval:
        due |= n == g
        g *= 2
    due |= (n > g // 2) & ((n - g // 2) % max_interval == 0) & (n >= g)
    return due


@dataclass
class RefitConfig:
    """How :class:`MotionRefitter` refits: the ``window`` of accepted fixes, the schedule's
    ``first`` refit and ``max_interval`` (fixes), the fewest accepted fixes a fit needs
    (``min_fixes``), the filter's walk component ``walk`` (σ_a, τ_v, probability, added
    variance), the smallest std a fit may give the fixes without a covariance,
    ``std_floor`` (m), and ``lag_s``, the data time (s) after a collar's refit point from
    which its new model filters (module docstring: *why a lag*)."""

    window: int = 200
    first: int = FIRST_REFIT
    min_fixes: int = 16
    max_interval: int = 1000
    walk: tuple | None = None
    std_floor: float = 0.02
    lag_s: float = 0.0


class ScheduledFit:
    """A collar's refitted model waiting to take over: from its first fix stamped at or
    after ``apply_at`` (s). ``fit`` is None for a fit that keeps the model (a prior) and
    while the fit runs in the background (``ready`` False); ``job`` is that fit's
    :class:`RefitJob` and ``index`` the collar's place in it."""

    __slots__ = ('apply_at', 'fit', 'ready', 'job', 'index')

    def __init__(self, apply_at: float, fit=None, ready: bool = True, job=None,
                 index: int = -1):
        self.apply_at, self.fit, self.ready = float(apply_at), fit, ready
        self.job, self.index = job, index


class MotionRefitter:
    """The accepted fixes of N collars in running windows, and their fitted models."""

    def __init__(self, n: int, config: RefitConfig | None = None):
        self.config = config or RefitConfig()
        W = int(self.config.window)
        self.n = int(n)
        self.seen = np.zeros(self.n, np.int64)        # fixes processed per collar
        self.t = np.zeros((self.n, W))
        self.z = np.zeros((self.n, W, 2))
        self.r = np.full((self.n, W), np.nan)
        self.count = np.zeros(self.n, np.int64)       # accepted fixes stored (≤ W)
        self.head = np.zeros(self.n, np.int64)        # next ring slot
        self.fits: list[MotionFit | None] = [None] * self.n
        #: per collar, the fitted models waiting to take over, oldest first
        self.scheduled = [deque() for _ in range(self.n)]
        self.refits = 0

    def due(self, collar, start_counts=None) -> np.ndarray:
        """(M,) whether each fix of a batch (collar indices, in order) is a refit point,
        counting from ``start_counts`` (default: the fixes seen so far)."""
        collar = np.asarray(collar, dtype=np.int64)
        seen = self.seen if start_counts is None else start_counts
        order = np.argsort(collar, kind='stable')
        c = collar[order]
        start, end = _runs(c)
        rank = np.arange(len(c)) - np.repeat(start, end - start)
        counts = np.empty(len(c), np.int64)
        counts[order] = seen[c] + rank + 1
        return refit_due(counts, self.config.first, self.config.max_interval)

    def observe(self, collar, stamp, east, north, var, accepted):
        """Take note of processed fixes (in order): every one counts towards the schedule;
        the accepted ones enter their collar's window (``var``: the fix's variance per axis,
        NaN if unknown)."""
        collar = np.asarray(collar, dtype=np.int64)
        np.add.at(self.seen, collar, 1)
        rows = np.flatnonzero(np.asarray(accepted, bool))
        if not len(rows):
            return
        W = self.t.shape[1]
        c = collar[rows]
        order = np.argsort(c, kind='stable')
        rows, c = rows[order], c[order]
        start, end = _runs(c)
        sizes = end - start
        u = c[start]                                       # each collar once, in order
        rank = np.arange(len(c)) - np.repeat(start, sizes)
        from_end = np.repeat(sizes, sizes) - rank          # 1 for a collar's last fix
        keep = from_end <= W                               # older ones would be overwritten
        rows, c, rank = rows[keep], c[keep], rank[keep]
        slot = (self.head[c] + rank) % W
        self.t[c, slot] = np.asarray(stamp, float)[rows]
        self.z[c, slot, 0] = np.asarray(east, float)[rows]
        self.z[c, slot, 1] = np.asarray(north, float)[rows]
        self.r[c, slot] = np.asarray(var, float)[rows]
        self.head[u] = (self.head[u] + sizes) % W
        self.count[u] = np.minimum(self.count[u] + sizes, W)

    def window(self, i: int):
        """Collar ``i``'s window, oldest first: (t, z, r)."""
        W = self.t.shape[1]
        k = self.count[i]
        idx = (self.head[i] - k + np.arange(k)) % W
        return self.t[i, idx], self.z[i, idx], self.r[i, idx]

    def refit(self, collars) -> dict:
        """Refit ``collars`` now (those with at least ``min_fixes`` accepted in their
        window); {collar: MotionFit} of the new models (not yet filtering: see
        :meth:`schedule`)."""
        job = self.prepare(collars)
        return self.accept(job, job.run()) if job is not None else {}

    def prepare(self, collars) -> RefitJob | None:
        """The refit of ``collars`` as a job that reads nothing of this refitter (copies of
        the windows and starting points, the configuration of now); None if no collar has
        the ``min_fixes`` a fit needs. A collar whose previous refit is still running
        starts from that refit's result (:meth:`RefitJob.run` resolves it)."""
        collars = [int(i) for i in collars if self.count[int(i)] >= self.config.min_fixes]
        if not collars:
            return None
        c = self.config
        start = []
        for i in collars:
            last = self.scheduled[i][-1] if self.scheduled[i] else None
            start.append(last if last is not None and not last.ready else self.fits[i])
        return RefitJob(collars, [self.window(i) for i in collars], start, c.min_fixes,
                        c.window, c.std_floor, c.walk)

    def accept(self, job: RefitJob, fits) -> dict:
        """Keep the models ``fits`` that ``job`` gave (a collar's 'prior' keeps its model);
        {collar: MotionFit} of the new ones."""
        out = {}
        for i, f in zip(job.collars, fits):
            if f.model == 'prior':
                continue
            self.fits[i] = f
            out[i] = f
        self.refits += len(out)
        return out

    def schedule(self, collar: int, due_stamp: float, fit=None, ready: bool = True,
                 job=None, index: int = -1) -> ScheduledFit:
        """A model for collar ``collar`` refitted at its fix stamped ``due_stamp``, to take
        over ``lag_s`` later (``fit`` None: it keeps its model; ``ready`` False: still
        being fitted by ``job``)."""
        entry = ScheduledFit(due_stamp + float(self.config.lag_s), fit, ready, job, index)
        self.scheduled[collar].append(entry)
        return entry

    def take_over(self, collar: int, stamp: float, use) -> bool:
        """Before collar ``collar``'s fix stamped ``stamp``: every scheduled model due by
        then takes over, oldest first (``use(fit)``: a bank's :func:`apply_fit`, or the
        reference filter's parameters). False (and nothing more done) at the first one
        still being fitted: the fix must wait for it."""
        queue = self.scheduled[collar]
        while queue and queue[0].apply_at <= stamp:
            if not queue[0].ready:
                return False
            entry = queue.popleft()
            if entry.fit is not None:
                use(entry.fit)
        return True


@dataclass
class RefitJob:
    """Refits to run (:meth:`MotionRefitter.prepare`): ``collars``, their ``windows``
    (t, z, r) and previous fits ``start``, and the fit's settings."""

    collars: list
    windows: list
    start: list
    min_fixes: int
    max_fixes: int
    std_floor: float
    walk: tuple | None

    @property
    def settings(self) -> tuple:
        """What the fit does with the windows (jobs alike in this can run as one)."""
        return (self.min_fixes, self.max_fixes, self.std_floor, self.walk)

    #: the :class:`ScheduledFit` of each collar (a job run in the background)
    entries: list | None = None
    #: after :meth:`run`: the fits, and the starting points they were fitted from
    result: list | None = None
    resolved: list | None = None

    @classmethod
    def merged(cls, jobs) -> RefitJob:
        """Jobs of the same :attr:`settings` as one (their collars' scheduled models now
        waiting for it)."""
        if len(jobs) == 1:
            return jobs[0]
        job = cls([i for j in jobs for i in j.collars], [w for j in jobs for w in j.windows],
                  [f for j in jobs for f in j.start], *jobs[0].settings)
        if all(j.entries is not None for j in jobs):
            job.entries = [e for j in jobs for e in j.entries]
            for k, e in enumerate(job.entries):
                e.job, e.index = job, k
        return job

    def run(self) -> list:
        """The fits (:func:`~herd_ros.ingest.motion_fit.fit_motion`), one per collar. A
        start that is a :class:`ScheduledFit` (the collar's previous refit, run before this
        one) becomes that refit's model, or its own start where it kept the model."""
        start = []
        for s in self.start:
            while isinstance(s, ScheduledFit):
                job, k = s.job, s.index
                fit = job.result[k] if job.result is not None else None
                s = fit if fit is not None and fit.model != 'prior' else (
                    job.resolved[k] if job.resolved is not None else job.start[k])
            start.append(s)
        self.resolved = start
        self.result = fit_motion(self.windows, min_fixes=self.min_fixes,
                                 max_fixes=self.max_fixes, position_std_floor=self.std_floor,
                                 walk=self.walk, start=start)
        # what a later refit may read of this one is its result and start: the windows and
        # the links to earlier refits go (a chain of them would hold every window ever fitted)
        self.windows, self.start = None, start
        return self.result


class BackgroundRefits:
    """The live node's refits off the fix path: a refit due after a collar's n-th fix runs
    in a worker thread while the fixes go on being filtered; a fix that needs the new model
    (stamped ``lag_s`` or more after the refit point, :class:`RefitConfig`) before it is
    ready waits for it (:class:`~herd_ros.ingest.fix_stream.FixStream` holds it, and its
    collar's later fixes), so every fix is filtered by the model :func:`process_with_refits`
    would have given it — the same states as offline, without a burst of refits (a herd of
    collars switched on together reaches its 20th fix together) stopping the fixes.

    One fit runs at a time; the refits that come due meanwhile wait and then run together
    in one vectorised call, oldest first, up to :data:`MAX_COLLARS` collars and never two
    refits of one collar (the later starts from the earlier's result; a collar's fit
    depends on its own window alone, so grouping changes nothing computed). The compiled
    kernels release the GIL (and split over :mod:`~herd_ros.ingest.collar_threads`), so
    the node's thread keeps working.
    """

    #: the most collars fitted in one call (more wait for the next): large enough to share
    #: each call's overhead, small enough that the first collars due are not held for all
    MAX_COLLARS = 256

    def __init__(self, bank, refitter: MotionRefitter):
        from concurrent.futures import ThreadPoolExecutor
        self.bank, self.refitter = bank, refitter
        self.pending = np.zeros(refitter.n, np.int64)   # refits queued or running
        self._queued: list[RefitJob] = []
        self._running: tuple | None = None              # (RefitJob, Future)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix='herd_refit',
                                        initializer=_background_thread)
        self.max_collars = self.MAX_COLLARS
        self.failures = 0
        self.last_failure = ''

    def submit(self, collars, stamps) -> np.ndarray:
        """Queue the refits of ``collars`` due at their fixes stamped ``stamps`` (their
        windows as they are now; each collar's new model scheduled, not yet fitted); the
        collars queued (those with the fixes a fit needs)."""
        job = self.refitter.prepare(collars)
        if job is None:
            return np.zeros(0, np.int64)
        due = dict(zip((int(i) for i in collars), (float(t) for t in stamps)))
        job.entries = [self.refitter.schedule(i, due[i], ready=False, job=job, index=k)
                       for k, i in enumerate(job.collars)]
        self._queued.append(job)
        started = np.asarray(job.collars, np.int64)
        np.add.at(self.pending, started, 1)
        self._start()
        return started

    def _start(self):
        """With no fit running: the oldest queued refits of the first one's settings, as
        one, up to :attr:`max_collars` collars and none twice (the first due are freed
        first)."""
        if self._running is not None or not self._queued:
            return
        key = self._queued[0].settings
        take, rest, size, seen = [], [], 0, set()
        for j in self._queued:
            ok = (not rest and j.settings == key and seen.isdisjoint(j.collars)
                  and (not take or size + len(j.collars) <= self.max_collars))
            if ok:
                take.append(j)
                size += len(j.collars)
                seen.update(j.collars)
            else:
                rest.append(j)
        self._queued = rest
        job = RefitJob.merged(take)
        self._running = (job, self._pool.submit(job.run))

    def finish(self, wait: bool = False) -> int:
        """Mark the finished refits' models ready to take over (every refit with
        ``wait``); the number of collars whose refit finished. A refit that failed leaves
        its collars' models as they were (counted in ``failures``)."""
        freed = 0
        while self._running is not None:
            job, future = self._running
            if not (wait or future.done()):
                break
            try:
                fits = future.result()
            except Exception as exc:  # noqa: BLE001 - a failed fit must not lose fixes
                self.failures += 1
                self.last_failure = f'{type(exc).__name__}: {exc}'
                fits = [None] * len(job.collars)
            else:
                self.refitter.accept(job, fits)
            for entry, fit in zip(job.entries, fits):
                entry.fit = fit if fit is not None and fit.model != 'prior' else None
                entry.ready = True
            job.entries = None
            np.subtract.at(self.pending, np.asarray(job.collars, np.int64), 1)
            freed += len(job.collars)
            self._running = None
            self._start()
        return freed

    @property
    def busy(self) -> bool:
        """Whether a refit is queued or running."""
        return self._running is not None

    @property
    def in_flight(self) -> int:
        """Collars whose refit is queued or running."""
        return int((self.pending > 0).sum())

    def close(self):
        """Stop the worker (after the refit running)."""
        self._pool.shutdown(wait=True)


#: how much lower the refit thread's scheduling priority is than the node's (nice)
BACKGROUND_NICE = 10


def _background_thread():
    """The refit worker's setup: its kernels on this one thread, at a lower priority
    (Linux: each thread its own nice value), so that the node's fix path keeps a core
    while 10 000 collars refit; the lag gives the refits the time (module docstring)."""
    import os
    import threading

    from herd_ros.ingest import collar_threads
    collar_threads.in_this_thread_only()
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BACKGROUND_NICE)
    except (AttributeError, OSError):            # not Linux, or not allowed: as it is
        pass


#: the largest HDOP taken as it is (a receiver's "no solution" value is often 99.9)
MAX_HDOP = 50.0


def fix_variance(cov_type, cov_ee, cov_nn, floor: float, hdop=None) -> np.ndarray:
    """A fix's variance per axis for the fit: the mean of its covariance's diagonal
    (floored) where NavSatFix gives one; otherwise NaN (unknown: σ_m², fitted), or −HDOP²
    for a fix with an HDOP (finite, > 0): σ_m² HDOP² if the collar's fit takes the HDOP
    (:func:`herd_ros.ingest.motion_fit.fit_motion`)."""
    cov_ee = np.asarray(cov_ee, float)
    cov_nn = np.asarray(cov_nn, float)
    known = (np.asarray(cov_type) != 0) & np.isfinite(cov_ee) & np.isfinite(cov_nn)
    with np.errstate(invalid='ignore'):
        v = np.maximum(0.5 * (cov_ee + cov_nn), floor * floor)
    out = np.where(known, v, np.nan)
    if hdop is not None:
        h = np.asarray(hdop, float)
        with np.errstate(invalid='ignore'):
            scaled = ~known & (h > 0) & np.isfinite(h)
        out = np.where(scaled, -np.minimum(h, MAX_HDOP) ** 2, out)
    return out


def fix_hdop(var) -> np.ndarray:
    """The HDOP of each fix that :func:`fix_variance` scaled (``var`` < 0), NaN for the
    rest."""
    var = np.asarray(var, float)
    with np.errstate(invalid='ignore'):
        return np.where(var < 0, np.sqrt(np.abs(var)), np.nan)


def apply_fit(bank, i: int, fit: MotionFit):
    """Collar ``i`` of ``bank`` moves by ``fit`` from its next fix on: the filter
    parameters :func:`herd_ros.ingest.pipeline.with_motion` gives the reference filter
    (:func:`~herd_ros.ingest.pipeline.fitted_motion`), its fix std and floor included."""
    from herd_ros.ingest.pipeline import fitted_motion
    bank.set_motion(i, *fitted_motion(bank.params, fit), hdop=bool(getattr(fit, 'hdop', False)))


def refit_rounds(stamps, bounds, config: RefitConfig) -> np.ndarray:
    """The round of each fix of a file processed whole (:func:`process_with_refits` on the
    fixes ordered by round): how many events of its collar came before it — its refit
    points (after the n-th fix) and the fixes from which their models filter (the first
    after the n-th stamped ``lag_s`` or more after it) — so that the rounds' boundaries are
    the only cuts. ``stamps`` (M,): the fixes sorted by collar (``bounds``: collar i's are
    ``stamps[bounds[i]:bounds[i + 1]]``), each collar's in stamp order."""
    stamps = np.asarray(stamps, float)
    m = len(stamps)
    sizes = np.diff(bounds)
    rank = np.arange(m) - np.repeat(bounds[:-1], sizes)          # 0-based within the collar
    points = np.flatnonzero(refit_due(np.arange(1, max(m, 1) + 1), config.first,
                                      config.max_interval)) + 1
    rounds = np.searchsorted(points, rank + 1, side='left')      # refit points before it
    if not len(points) or not m:
        return rounds
    # the take-over fix of each (collar, refit point): one sorted search over all collars,
    # each collar's stamps shifted past the previous collar's
    collar = np.repeat(np.arange(len(sizes)), sizes)
    lag = float(config.lag_s)
    rel = stamps - stamps.min()
    span = float(rel.max()) + lag + 1.0
    key = rel + collar * span
    for P in points:
        have = np.flatnonzero(sizes >= P)
        if not len(have):
            break
        at = bounds[:-1][have] + P - 1                            # the refit point's fix
        hit = np.searchsorted(key, key[at] + lag, side='left')
        hit = np.maximum(hit, at + 1)                            # after the refit point
        ends = bounds[1:][have]
        ok = hit < ends
        # the fixes of the collar from the take-over fix on are one round later
        mark = np.zeros(m + 1, np.int64)
        np.add.at(mark, hit[ok], 1)
        np.add.at(mark, ends[ok], -1)
        rounds = rounds + np.cumsum(mark)[:m]
    return rounds


def stabbing_cuts(lo, hi) -> list[int]:
    """The fewest positions c with lo < c ≤ hi for every interval (lo, hi] (the greedy
    stabbing of intervals by their right ends), sorted."""
    cuts, last = [], -1
    for left, h in sorted(zip(np.asarray(lo).tolist(), np.asarray(hi).tolist()),
                          key=lambda lh: lh[1]):
        if left < last:                 # a cut at `last` (≤ h) already stabs it
            continue
        cuts.append(int(h))
        last = int(h)
    return cuts


def _runs(c) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) of the runs of equal values of the sorted (M,) array ``c``:
    ``c[starts[k]:ends[k]]`` is the k-th (np.concatenate, not np.r_: a batch's hot path)."""
    m = len(c)
    if not m:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    starts = np.flatnonzero(np.concatenate(([True], c[1:] != c[:-1])))
    return starts, np.concatenate((starts[1:], [m]))


def _neighbours(collar) -> tuple[np.ndarray, np.ndarray]:
    """(M,) the next position of each fix's collar in the batch (M if none) and the
    previous one (-1 if none)."""
    m = len(collar)
    order = np.argsort(collar, kind='stable')
    nxt, prv = np.full(m, m, np.int64), np.full(m, -1, np.int64)
    same = collar[order[1:]] == collar[order[:-1]]
    nxt[order[:-1][same]] = order[1:][same]
    prv[order[1:][same]] = order[:-1][same]
    return nxt, prv


def _refit_plan(refitter: MotionRefitter, collar, stamp):
    """The events of a batch: which fixes are refit points (``due`` (M,)), and the cuts
    (:func:`stabbing_cuts`) that put each refit after its point and before its collar's
    next fix, and each scheduled model's take-over between the fix before the first one it
    filters and that fix (the models scheduled already and those of the batch's own refit
    points). Returns (due, cuts, first (collar -> its first position, for the collars with
    a model scheduled or a refit point here))."""
    m = len(collar)
    due = refitter.due(collar)
    nxt, prv = _neighbours(collar)
    p = np.flatnonzero(due)
    inside = nxt[p] < m
    lo, hi = list(p[inside]), list(nxt[p][inside])
    lag = float(refitter.config.lag_s)
    order = np.argsort(collar, kind='stable')
    c_sorted = collar[order]
    starts, ends = _runs(c_sorted)
    first = {}
    # a collar with one fix in the batch (the live node's common case: a batch of a few
    # milliseconds) needs no cut: nothing of it comes before that fix
    single = ends - starts == 1
    scheduled = refitter.scheduled
    for c, q in zip(c_sorted[starts[single]].tolist(), order[starts[single]].tolist()):
        if scheduled[c] or due[q]:
            first[c] = q
    for s0, end in zip(starts[~single].tolist(), ends[~single].tolist()):
        c = int(c_sorted[s0])
        pos = order[s0:end]                     # the collar's positions, in batch order
        points = pos[due[pos]]
        if not scheduled[c] and not len(points):
            continue
        first[c] = int(pos[0])
        times = [(e.apply_at, -1) for e in scheduled[c]]
        times += [(float(stamp[q]) + lag, int(q)) for q in points]
        st = stamp[pos]
        for apply_at, origin in times:
            after = pos > origin
            hit = np.flatnonzero(after & (st >= apply_at))
            if len(hit) and prv[pos[hit[0]]] >= 0:
                a = int(pos[hit[0]])
                lo.append(int(prv[a]))
                hi.append(a)
    return due, stabbing_cuts(lo, hi), first


def _drive(bank, refitter: MotionRefitter, rows, refit_now, out: FixBatch, motion):
    """Process a batch (``rows``: collar, stamp, east, north, status, cov_type, cov9, var)
    part by part, the refits due fitted (``refit_now``, sync) or submitted (the
    background's ``submit``) at each cut, and the scheduled models taking over before the
    fixes they filter. Returns the (M,) mask of the fixes held: their collar's model was not
    ready (from that fix on, the collar's fixes in the batch are left unprocessed)."""
    collar, stamp = rows[0], rows[1]
    m = len(collar)
    held = np.zeros(m, bool)
    due, cuts, first = _refit_plan(refitter, collar, stamp)
    nxt, _ = _neighbours(collar)

    def take_over_at(c: int, q: int):
        if not held[q] and not refitter.take_over(
                c, float(stamp[q]), lambda fit: apply_fit(bank, c, fit)):
            held[(collar == c) & (np.arange(m) >= q)] = True

    for c, q in first.items():
        if refitter.scheduled[c]:
            take_over_at(c, q)
    start = 0
    for stop in cuts + [m]:
        if stop > start:
            if held[start:stop].any():
                go = start + np.flatnonzero(~held[start:stop])
                part = tuple(a[go] for a in rows)
                batch, mo = FixBatch.empty(len(go)), np.empty((len(go), 2))
                process_observed(bank, refitter, *part, batch, mo)
                out.put(go, batch)
                motion[go] = mo
            else:                                   # the whole part: views, no copies
                go = np.arange(start, stop)
                sl = slice(start, stop)
                process_observed(bank, refitter, *(a[sl] for a in rows), out.rows(sl),
                                 motion[sl])
            points = go[due[go]]
            if len(points):
                refit_now(collar[points], stamp[points])
            # the models due by each collar's next fix (after this part) take over
            later = nxt[go]
            for q in np.unique(later[later >= stop]).tolist():
                if q < m:
                    c = int(collar[q])
                    if refitter.scheduled[c]:
                        take_over_at(c, q)
        start = stop
    return held


def process_with_refits(bank, refitter: MotionRefitter, collar, stamp, east, north,
                        status, cov_type, cov9, var):
    """:meth:`CollarBank.process` of a batch with the refits it contains (module
    docstring), fitted at once: returns (FixBatch, motion (M, 2)) — ``motion`` the model
    (σ_a, τ_v) each fix's collar had when the fix was processed (what carries its state
    forward). ``cov_type``, ``cov9``: the fixes' NavSatFix covariances (their R is formed
    part by part: a refit changes the std of its collar's fixes without one); ``var``: the
    fixes' variances for the fit (:func:`fix_variance`)."""
    collar = np.ascontiguousarray(collar, dtype=np.int64)
    rows = (collar, stamp, east, north, status, cov_type, cov9, var)
    out = FixBatch.empty(len(collar))
    motion = np.empty((len(collar), 2))

    def refit_now(collars, stamps):
        due = dict(zip(collars.tolist(), stamps.tolist()))
        for i, fit in refitter.refit(np.unique(collars)).items():
            refitter.schedule(i, due[i], fit)

    _drive(bank, refitter, rows, refit_now, out, motion)
    return out, motion


def process_deferring(bank, refitter: MotionRefitter, background: BackgroundRefits, rows):
    """:func:`process_with_refits` of a batch with the refits in the background: they are
    submitted at their points, and the fixes that need a model not yet fitted are held.
    Returns (FixBatch, motion, held (M,)): the rows not held filtered, as
    :func:`process_with_refits` would have."""
    collar = np.ascontiguousarray(rows[0], dtype=np.int64)
    rows = (collar,) + tuple(rows[1:])
    out = FixBatch.empty(len(collar))
    motion = np.empty((len(collar), 2))
    held = _drive(bank, refitter, rows, background.submit, out, motion)
    return out, motion, held


def process_observed(bank, refitter: MotionRefitter, collar, stamp, east, north, status,
                     cov_type, cov9, var, out: FixBatch, motion):
    """:meth:`CollarBank.process` of fixes with no refit due before any collar's last one
    among them, each counted and (accepted) put in its window: the states in ``out``, the
    model each fix's collar had in ``motion`` (M, 2) (see :func:`process_with_refits`)."""
    motion[:, 0] = bank.accel_std[collar]
    motion[:, 1] = bank.velocity_tau[collar]
    R = bank.measurement_covariances(cov_type, cov9, collar, fix_hdop(var))
    bank.process(collar, stamp, east, north, status, R, out=out)
    refitter.observe(collar, stamp, east, north, var, out.accepted)
