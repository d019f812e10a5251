"""The collar kernels on several threads (:mod:`herd_ros.ingest.collar_threads`).

A collar's filter and motion fit depend on its own fixes alone, so splitting the collars
over threads must give the numbers of one call, bit for bit; and the split only pays if
the compiled kernels let go of the GIL while they run.
"""
import threading
import time

import numpy as np
import pytest

from herd_ros.ingest import collar_threads
from herd_ros.ingest.collar_bank import CollarBank
from herd_ros.ingest.collar_filter import FilterParams
from herd_ros.ingest.motion_fit import fit_motion


def collars(n=12, fixes=300, seed=3):
    """n collars' fixes every 30-300 s, a correlated walk with 5 m noise and 2 % outliers
    500 m off, interleaved in time."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        t = 1.7e9 + np.cumsum(rng.uniform(30, 300, fixes))
        v = np.cumsum(rng.normal(0, 0.05, (fixes, 2)), axis=0).clip(-0.5, 0.5)
        p = np.cumsum(v * 60, axis=0) + rng.normal(0, 5, (fixes, 2))
        p[rng.random(fixes) < 0.02] += 500
        rows.append((np.full(fixes, i), t, p))
    c = np.concatenate([r[0] for r in rows])
    t = np.concatenate([r[1] for r in rows])
    p = np.concatenate([r[2] for r in rows])
    order = np.argsort(t, kind='stable')
    return c[order], t[order], p[order]


def test_split_covers_every_collar_once_in_parts_of_about_equal_work():
    work = np.r_[np.full(10, 1000.0), 0.0, np.full(10, 3000.0)]
    parts = collar_threads.split(work, parts=4)
    covered = np.concatenate([np.arange(21)[sl] for sl in parts])
    np.testing.assert_array_equal(covered, np.arange(21))
    shares = [work[sl].sum() / work.sum() for sl in parts]
    assert len(parts) == 4 and max(shares) <= 0.25 + 3000 / work.sum()
    # too little work, one collar, one thread: one part
    assert collar_threads.split(np.full(3, 10.0), parts=4) == [slice(0, 3)]
    assert collar_threads.split([1e9], parts=4) == [slice(0, 1)]
    assert collar_threads.split(work, parts=1) == [slice(0, 21)]


def test_thread_count_reads_the_environment(monkeypatch):
    monkeypatch.setenv(collar_threads.ENV, '3')
    assert collar_threads.thread_count() == 3
    monkeypatch.setenv(collar_threads.ENV, '0')
    with pytest.raises(ValueError, match='at least 1'):
        collar_threads.thread_count()
    monkeypatch.setenv(collar_threads.ENV, 'many')
    with pytest.raises(ValueError, match='whole number'):
        collar_threads.thread_count()
    monkeypatch.delenv(collar_threads.ENV)
    assert 1 <= collar_threads.thread_count() <= collar_threads.MAX_THREADS


def test_run_returns_results_in_order_and_reraises():
    assert collar_threads.run([lambda: 1, lambda: 2, lambda: 3]) == [1, 2, 3]

    def boom():
        raise ZeroDivisionError('part 2')

    with pytest.raises(ZeroDivisionError, match='part 2'):
        collar_threads.run([lambda: 1, boom, lambda: 3])


def bank_run(c, t, p, threads, monkeypatch):
    monkeypatch.setenv(collar_threads.ENV, str(threads))
    params = FilterParams(accel_std=0.05, velocity_tau=120.0, stale_after=600.0,
                          walk_accel_std=0.1, walk_velocity_tau=60.0)
    bank = CollarBank(int(c.max()) + 1, params)
    R = bank.measurement_covariances(np.zeros(len(c), np.int64), np.full((len(c), 9), np.nan))
    out = []
    for sl in (slice(0, len(c) // 2), slice(len(c) // 2, None)):   # two batches
        res = bank.process(c[sl], t[sl], p[sl, 0], p[sl, 1], np.zeros(len(c[sl]), np.int64),
                           R[sl])
        out.append((res.outcome.copy(), res.x.copy(), res.P.copy(), res.segment.copy()))
    return out, bank.x.copy(), bank.counters.copy()


def test_the_bank_gives_the_same_numbers_on_one_thread_or_several(kernels, monkeypatch):
    monkeypatch.setattr(collar_threads, 'MIN_WORK', 100)     # split even this small herd
    c, t, p = collars()
    one = bank_run(c, t, p, 1, monkeypatch)
    assert len(collar_threads.split(np.bincount(c), parts=3)) == 3   # really split
    three = bank_run(c, t, p, 3, monkeypatch)
    for (a, b) in zip(one[0], three[0]):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(one[1], three[1])
    np.testing.assert_array_equal(one[2], three[2])
    assert (one[0][0][0] == 0).sum() > 1000           # most fixes accepted: a real run


def test_the_motion_fit_gives_the_same_models_on_one_thread_or_several(kernels,
                                                                       monkeypatch):
    monkeypatch.setattr(collar_threads, 'MIN_WORK', 100)
    c, t, p = collars()
    tracks = [(t[c == i], p[c == i], np.full((c == i).sum(), np.nan)) for i in range(12)]
    fits = {}
    for threads in (1, 3):
        monkeypatch.setenv(collar_threads.ENV, str(threads))
        fits[threads] = fit_motion(tracks, walk=(0.1, 60.0, 0.1))
    assert fits[1] == fits[3]
    assert {f.model for f in fits[1]} <= {'rw', 'iou'}


def test_the_compiled_kernels_let_other_threads_run(kernels):
    """While a thread is inside a long kernel call, this thread keeps waking from 1 ms
    sleeps: with the GIL held it could not run again until the call returned."""
    rng = np.random.default_rng(0)
    N, W = 60, 400
    t = np.cumsum(rng.uniform(20, 60, (N, W)), axis=1)
    z = np.cumsum(rng.normal(0, 3, (N, W, 2)), axis=1)
    r = np.full((N, W), np.nan)
    n = np.full(N, W, np.int64)
    x0 = np.tile([2.0, -2.0, 1.0], (N, 1))
    lo = np.tile([0.0, -8.0, -1.0], (N, 1))
    hi = np.tile([5.0, 4.0, 4.0], (N, 1))
    step = np.full((N, 3), 0.5)
    x, ll = np.empty((N, 3)), np.empty(N)
    span = []

    def call():
        t0 = time.perf_counter()
        kernels.motion_nelder_mead(t, z, r, n, x0, lo, hi, step, 0.0, 0.0, 0.0, 0.0, 5.99,
                                   np.full(N, 300, np.int64), 1e-12, x, ll)
        span.extend([t0, time.perf_counter()])

    worker = threading.Thread(target=call)
    wakes = []
    worker.start()
    while worker.is_alive():
        time.sleep(0.001)
        wakes.append(time.perf_counter())
    worker.join()
    t0, t1 = span
    assert np.isfinite(ll).all() and t1 - t0 > 0.05, 'the call was too short to tell'
    inside = sum(t0 + 0.01 < w < t1 - 0.002 for w in wakes)
    assert inside >= 5, (f'woke {inside} times during a {t1 - t0:.2f} s kernel call: '
                         f'the GIL was held')
