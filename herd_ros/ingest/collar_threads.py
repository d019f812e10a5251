"""The collar kernels on several cores: collars split into parts of about equal work, each
part's kernel call in a thread of its own.

A collar's filter and its motion fit depend on its own fixes alone (the kernels of
:mod:`herd_ros.ingest.collar_kernels` read and write only the rows of the collars they are
given), and the compiled kernels release the GIL (``nogil`` in the JIT path; the
ahead-of-time build is told to, :func:`herd_ros.ingest.aot.compiler`). So a batch split by
collar runs on as many cores as there are parts and gives the same numbers, bit for bit,
as one call: the split changes which thread computes a collar, never what is computed.

``HERD_ROS_THREADS`` sets the number of threads (default: the cores this process may run
on, at most :data:`MAX_THREADS`; 1 runs every call in the calling thread).

Plain numpy and the standard library; no ROS.
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

#: environment variable: how many threads the collar kernels use
ENV = 'HERD_ROS_THREADS'
#: the most threads used by default
MAX_THREADS = 8
#: below this much work (fixes × likelihood evaluations, or fixes) a batch is not split
MIN_WORK = 5_000

_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()
_local = threading.local()


def in_this_thread_only():
    """From now on the collar kernels called from this thread run in it alone (no split):
    a background thread that must leave the other cores to the fix path."""
    _local.alone = True


def thread_count() -> int:
    """Threads for the collar kernels: :data:`ENV` if set (≥ 1), else the cores this
    process may run on, at most :data:`MAX_THREADS`."""
    text = os.environ.get(ENV, '').strip()
    if text:
        try:
            n = int(text)
        except ValueError:
            raise ValueError(f'{ENV} must be a whole number of threads, got {text!r}') from None
        if n < 1:
            raise ValueError(f'{ENV} must be at least 1, got {n}')
        return n
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:                       # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_THREADS))


def split(work, parts: int | None = None) -> list[slice]:
    """Contiguous slices of the collars ``0..len(work)-1`` with about equal total ``work``
    each (at most ``parts``, default :func:`thread_count`; one slice when the whole is
    below :data:`MIN_WORK` or there is one collar)."""
    work = np.maximum(np.asarray(work, dtype=float), 0.0)
    n = len(work)
    total = float(work.sum())
    if n <= 1 or total < MIN_WORK:                  # before thread_count(): a hot path
        return [slice(0, n)]
    if getattr(_local, 'alone', False):
        return [slice(0, n)]
    parts = min(thread_count() if parts is None else int(parts), n)
    if parts <= 1:
        return [slice(0, n)]
    edges = np.searchsorted(np.cumsum(work), total * np.arange(1, parts) / parts,
                            side='left') + 1
    edges = np.unique(np.clip(np.r_[0, edges, n], 0, n))
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def run(calls) -> list:
    """Run the thunks ``calls`` at once (the first in this thread), their results in order;
    the first exception raised is re-raised once all have ended."""
    calls = list(calls)
    if len(calls) <= 1:
        return [c() for c in calls]
    global _pool
    with _pool_lock:
        if _pool is None or _pool._max_workers < len(calls) - 1:
            _pool = ThreadPoolExecutor(max_workers=max(len(calls) - 1, MAX_THREADS - 1),
                                       thread_name_prefix='herd_ros-collars')
        pool = _pool
    futures = [pool.submit(c) for c in calls[1:]]
    results, error = [], None
    try:
        results.append(calls[0]())
    except BaseException as exc:                 # noqa: BLE001 (re-raised below)
        error = exc
    for f in futures:
        try:
            results.append(f.result())
        except BaseException as exc:             # noqa: BLE001
            error = error or exc
    if error is not None:
        raise error
    return results
