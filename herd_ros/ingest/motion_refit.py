"""Each collar's motion model refitted as its fixes arrive: the same causal schedule live
and offline.

A collar starts with a prior that follows its fixes (a random walk with the configured
model's diffusion, :func:`herd_ros.ingest.pipeline.with_walk`). Right after its n-th fix
(any outcome) for n in :func:`refit_due`'s schedule — 20, 40, 80, ..., doubling up to
``max_interval`` fixes
apart, then every ``max_interval`` fixes — its model is refitted by maximum likelihood
(:func:`herd_ros.ingest.motion_fit.fit_motion`, warm-started from its previous fit) on its
last ``window`` accepted fixes, and that model filters its next fixes. The fit only ever
sees fixes the filter already had, so the track stays causal, and since a collar's fit
depends on its own fixes alone, the ``gps_ingest`` node (fixes in arrival order, in
batches) and ``herd-ros ingest`` (a whole file at once) refit at the same fixes and give the
same states.

:func:`process_with_refits` drives a :class:`~herd_ros.ingest.collar_bank.CollarBank`
through a batch: it splits the batch only where a refit must come before a collar's next
fix, so refits due together are fitted together (one vectorised call).

Plain numpy; no ROS.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from herd_ros.ingest.collar_bank import FixBatch
from herd_ros.ingest.motion_fit import MotionFit, fit_motion

#: first refit (fixes), the schedule doubles from here
FIRST_REFIT = 20


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
    variance) and the smallest std a fit may give the fixes without a covariance,
    ``std_floor`` (m)."""

    window: int = 200
    first: int = FIRST_REFIT
    min_fixes: int = 16
    max_interval: int = 1000
    walk: tuple | None = None
    std_floor: float = 0.02


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
        self.refits = 0

    def due(self, collar, start_counts=None) -> np.ndarray:
        """(M,) whether each fix of a batch (collar indices, in order) is a refit point,
        counting from ``start_counts`` (default: the fixes seen so far)."""
        collar = np.asarray(collar, dtype=np.int64)
        seen = self.seen if start_counts is None else start_counts
        order = np.argsort(collar, kind='stable')
        c = collar[order]
        first = np.r_[True, c[1:] != c[:-1]] if len(c) else np.zeros(0, bool)
        start = np.flatnonzero(first)
        rank = np.arange(len(c)) - np.repeat(start, np.diff(np.r_[start, len(c)]))
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
        start = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
        sizes = np.diff(np.r_[start, len(c)])
        rank = np.arange(len(c)) - np.repeat(start, sizes)
        from_end = np.repeat(sizes, sizes) - rank          # 1 for a collar's last fix
        keep = from_end <= W                               # older ones would be overwritten
        rows, c, rank = rows[keep], c[keep], rank[keep]
        slot = (self.head[c] + rank) % W
        self.t[c, slot] = np.asarray(stamp, float)[rows]
        self.z[c, slot, 0] = np.asarray(east, float)[rows]
        self.z[c, slot, 1] = np.asarray(north, float)[rows]
        self.r[c, slot] = np.asarray(var, float)[rows]
        u = c[np.r_[True, c[1:] != c[:-1]]]
        self.head[u] = (self.head[u] + sizes) % W
        self.count[u] = np.minimum(self.count[u] + sizes, W)

    def window(self, i: int):
        """Collar ``i``'s window, oldest first: (t, z, r)."""
        W = self.t.shape[1]
        k = self.count[i]
        idx = (self.head[i] - k + np.arange(k)) % W
        return self.t[i, idx], self.z[i, idx], self.r[i, idx]

    def refit(self, collars) -> dict:
        """Refit ``collars`` (those with at least ``min_fixes`` accepted in their window);
        {collar: MotionFit} of the new models."""
        job = self.prepare(collars)
        return self.accept(job, job.run()) if job is not None else {}

    def prepare(self, collars) -> RefitJob | None:
        """The refit of ``collars`` as a job that reads nothing of this refitter (copies of
        the windows and starting points, the configuration of now); None if no collar has
        the ``min_fixes`` a fit needs."""
        collars = [int(i) for i in collars if self.count[int(i)] >= self.config.min_fixes]
        if not collars:
            return None
        c = self.config
        return RefitJob(collars, [self.window(i) for i in collars],
                        [self.fits[i] for i in collars], c.min_fixes, c.window, c.std_floor,
                        c.walk)

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

    @classmethod
    def merged(cls, jobs) -> RefitJob:
        """Jobs of the same :attr:`settings` as one."""
        if len(jobs) == 1:
            return jobs[0]
        return cls([i for j in jobs for i in j.collars], [w for j in jobs for w in j.windows],
                   [f for j in jobs for f in j.start], *jobs[0].settings)

    def run(self) -> list:
        """The fits (:func:`~herd_ros.ingest.motion_fit.fit_motion`), one per collar."""
        return fit_motion(self.windows, min_fixes=self.min_fixes, max_fixes=self.max_fixes,
                          position_std_floor=self.std_floor, walk=self.walk,
                          start=self.start)


class BackgroundRefits:
    """The live node's refits off the fix path: a refit due after a collar's n-th fix runs
    in a worker thread while the other collars' fixes go on being filtered; the collar's
    own later fixes wait (:class:`~herd_ros.ingest.fix_stream.FixStream` holds them) until
    its new model is in the bank, so every fix is filtered by the model
    :func:`process_with_refits` would have given it — the same states as offline, without
    a burst of refits (a herd of collars switched on together reaches its 20th fix
    together) stopping every collar's fixes.

    One fit runs at a time; the refits that come due meanwhile wait and then run together
    in one vectorised call, oldest first, up to :data:`MAX_COLLARS` collars (a collar's
    fit depends on its own window alone, so grouping changes nothing computed). The
    compiled kernels release the GIL (and split over
    :mod:`~herd_ros.ingest.collar_threads`), so the node's thread keeps working.
    """

    #: the most collars fitted in one call (more wait for the next): large enough to share
    #: each call's overhead, small enough that the first collars due are not held for all
    MAX_COLLARS = 256

    def __init__(self, bank, refitter: MotionRefitter):
        from concurrent.futures import ThreadPoolExecutor
        self.bank, self.refitter = bank, refitter
        self.pending = np.zeros(refitter.n, bool)       # a refit queued or running
        self._queued: list[RefitJob] = []
        self._running: tuple | None = None              # (RefitJob, Future)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix='herd_refit')
        self.max_collars = self.MAX_COLLARS
        self.failures = 0
        self.last_failure = ''

    def submit(self, collars) -> np.ndarray:
        """Queue the refits of ``collars`` (their windows as they are now); the collars now
        pending (those with the fixes a fit needs)."""
        job = self.refitter.prepare(collars)
        if job is None:
            return np.zeros(0, np.int64)
        self._queued.append(job)
        started = np.asarray(job.collars, np.int64)
        self.pending[started] = True
        self._start()
        return started

    def _start(self):
        """With no fit running: the oldest queued refits of the first one's settings, as
        one, up to :attr:`max_collars` collars (the first due are freed first)."""
        if self._running is not None or not self._queued:
            return
        key = self._queued[0].settings
        take, rest, size = [], [], 0
        for j in self._queued:
            if j.settings == key and size < self.max_collars:
                take.append(j)
                size += len(j.collars)
            else:
                rest.append(j)
        self._queued = rest
        job = RefitJob.merged(take)
        self._running = (job, self._pool.submit(job.run))

    def finish(self, wait: bool = False) -> int:
        """Put the finished refits' models in the bank (every refit with ``wait``); the
        number of collars freed. A refit that failed leaves its collars' models as they were
        (counted in ``failures``)."""
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
            else:
                for i, fit in self.refitter.accept(job, fits).items():
                    apply_fit(self.bank, i, fit)
            self.pending[job.collars] = False
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
        return int(self.pending.sum())

    def close(self):
        """Stop the worker (after the refit running)."""
        self._pool.shutdown(wait=True)


def fix_variance(cov_type, cov_ee, cov_nn, floor: float) -> np.ndarray:
    """A fix's variance per axis for the fit: the mean of its covariance's diagonal
    (floored) where NavSatFix gives one, NaN (unknown: fitted) otherwise."""
    cov_ee = np.asarray(cov_ee, float)
    cov_nn = np.asarray(cov_nn, float)
    known = (np.asarray(cov_type) != 0) & np.isfinite(cov_ee) & np.isfinite(cov_nn)
    with np.errstate(invalid='ignore'):
        v = np.maximum(0.5 * (cov_ee + cov_nn), floor * floor)
    return np.where(known, v, np.nan)


def apply_fit(bank, i: int, fit: MotionFit):
    """Collar ``i`` of ``bank`` moves by ``fit`` from its next fix on: the filter
    parameters :func:`herd_ros.ingest.pipeline.with_motion` gives the reference filter
    (:func:`~herd_ros.ingest.pipeline.fitted_motion`), its fix std and floor included."""
    from herd_ros.ingest.pipeline import fitted_motion
    bank.set_motion(i, *fitted_motion(bank.params, fit))


def split_points(collar, due) -> list[int]:
    """Where to split a batch so that each refit comes before its collar's next fix:
    positions p such that the batch is processed as [0, p₁), [p₁, p₂), ... with the refits
    due in a part done after it. The fewest splits (greedy stabbing of the intervals
    (boundary, next fix of the collar])."""
    collar = np.asarray(collar, dtype=np.int64)
    pos = np.flatnonzero(due)
    if not len(pos):
        return []
    order = np.argsort(collar, kind='stable')
    nxt = np.full(len(collar), len(collar), np.int64)
    same = collar[order[1:]] == collar[order[:-1]]
    nxt[order[:-1][same]] = order[1:][same]
    ends = nxt[pos]                       # the refit must happen before this position
    inside = ends < len(collar)
    cuts = []
    last = -1
    for p, e in sorted(zip(pos[inside], ends[inside]), key=lambda pe: pe[1]):
        if p < last:                      # a cut at `last` (≤ e) already follows p
            continue
        cuts.append(int(e))
        last = int(e)
    return cuts


def process_with_refits(bank, refitter: MotionRefitter, collar, stamp, east, north,
                        status, cov_type, cov9, var):
    """:meth:`CollarBank.process` of a batch with the refits it contains (module
    docstring): returns (FixBatch, motion (M, 2)) — ``motion`` the model (σ_a, τ_v) each
    fix's collar had when the fix was processed (what carries its state forward).
    ``cov_type``, ``cov9``: the fixes' NavSatFix covariances (their R is formed part by
    part: a refit changes the std of its collar's fixes without one); ``var``: the fixes'
    variances for the fit (:func:`fix_variance`)."""
    collar = np.ascontiguousarray(collar, dtype=np.int64)
    m = len(collar)
    out = FixBatch.empty(m)
    motion = np.empty((m, 2))
    due = refitter.due(collar)
    cuts = split_points(collar, due) + [m]
    start = 0
    for stop in cuts:
        if stop <= start:
            continue
        sl = slice(start, stop)
        c = collar[sl]
        process_observed(bank, refitter, c, stamp[sl], east[sl], north[sl], status[sl],
                         cov_type[sl], cov9[sl], var[sl], out.rows(sl), motion[sl])
        for i, fit in refitter.refit(np.unique(c[due[sl]])).items():
            apply_fit(bank, i, fit)
        start = stop
    return out, motion


def process_observed(bank, refitter: MotionRefitter, collar, stamp, east, north, status,
                     cov_type, cov9, var, out: FixBatch, motion):
    """:meth:`CollarBank.process` of fixes with no refit due before any collar's last one
    among them, each counted and (accepted) put in its window: the states in ``out``, the
    model each fix's collar had in ``motion`` (M, 2) (see :func:`process_with_refits`)."""
    motion[:, 0] = bank.accel_std[collar]
    motion[:, 1] = bank.velocity_tau[collar]
    R = bank.measurement_covariances(cov_type, cov9, collar)
    bank.process(collar, stamp, east, north, status, R, out=out)
    refitter.observe(collar, stamp, east, north, var, out.accepted)


def after_first_due(collar, due) -> np.ndarray:
    """(M,) whether each fix of a batch comes after a refit point of its own collar in the
    batch (those must wait for the refit)."""
    collar = np.asarray(collar, dtype=np.int64)
    order = np.argsort(collar, kind='stable')
    d = np.asarray(due, bool)[order].astype(np.int64)
    c = collar[order]
    before = np.cumsum(d) - d                       # refit points strictly before, overall
    start = np.flatnonzero(np.r_[True, c[1:] != c[:-1]]) if len(c) else np.zeros(0, int)
    base = np.repeat(before[start], np.diff(np.r_[start, len(c)]))
    out = np.empty(len(c), bool)
    out[order] = before - base > 0
    return out
