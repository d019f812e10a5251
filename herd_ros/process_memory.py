"""A batch process that keeps the memory it freed, instead of handing it back and faulting
it in again.

glibc's malloc serves a request of more than ``M_MMAP_THRESHOLD`` (128 KiB, raised
dynamically up to 32 MiB) with a fresh ``mmap`` and gives it back with ``munmap`` when it
is freed, and trims the top of its heap past ``M_TRIM_THRESHOLD``. A numpy pipeline makes
and drops arrays of megabytes all the time, so each new array is a new mapping whose every
page faults in, zeroed by the kernel, once more: on ``herd-ros ingest`` of 360 000 fixes
~108 000 page faults and 0.3-0.9 s of system time (on this machine's virtual machine, whose
page faults are slow and vary). Served from a heap that is kept, the freed pages are
reused: ~75 000 faults, 0.2 s.

:func:`keep_freed_memory` sets both thresholds (``mallopt``, glibc only) for the rest of
the process. What it costs is that the process gives no memory back before it ends, and
its peak can rise by what the heap cannot reuse: +4 % on that ingest (452 against 436 MiB,
for 0.95 x the wall time, farm-bench, 10 pairs), +8 % on ``herd-ros fit`` of the steers'
72 h (1 012 against 941 MiB, no faster). So a verb asks for it (``KEEPS_FREED_MEMORY =
True`` in its module: ``herd-ros ingest``); the other verbs and the nodes keep glibc's
defaults, and ``HERD_ROS_MALLOC=default`` leaves them to ingest too.
"""
from __future__ import annotations

import os

#: environment variable: ``default`` keeps glibc's malloc settings
ENV = 'HERD_ROS_MALLOC'
#: mallopt parameter numbers (glibc's malloc.h)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
#: the threshold set for both: blocks up to 1 GiB come from the heap, which is never trimmed
THRESHOLD = 1 << 30


def keep_freed_memory() -> bool:
    """Tell glibc's malloc to serve blocks up to :data:`THRESHOLD` from its heap and not to
    trim it (module docstring). Returns True if both were set; False elsewhere (not glibc,
    or ``HERD_ROS_MALLOC=default``), where nothing changes."""
    if os.environ.get(ENV, '').strip().lower() == 'default':
        return False
    try:
        import ctypes
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
        mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
        return bool(mallopt(M_MMAP_THRESHOLD, THRESHOLD)) and bool(
            mallopt(M_TRIM_THRESHOLD, THRESHOLD))
    except (AttributeError, OSError):
        return False
