"""The two guards against wrong stamps, one place for the live ingest
(:class:`~herd_ros.ingest.fix_stream.FixStream`) and the offline one
(:func:`~herd_ros.ingest.pipeline.trajectory_from_fixes`): a stamp far in the future, and a
jump of data time (a collar stamped 0 at boot, a file holding two recordings)."""
from __future__ import annotations

import numpy as np

#: the defaults of gps_ingest's max_stamp_ahead_s and max_clock_jump_s (s)
MAX_STAMP_AHEAD_S = 600.0
MAX_CLOCK_JUMP_S = 3600.0


def future_stamps(stamp: np.ndarray, now: float, max_ahead: float) -> np.ndarray:
    """Mask of stamps more than ``max_ahead`` s after ``now`` (the wall clock): one wrong
    stamp must not drag the herd clock into the future."""
    return np.asarray(stamp, float) > now + max_ahead


def clock_jumps(herd_time: float, stamp: np.ndarray, max_jump: float) -> tuple[list, np.ndarray]:
    """(indices where data time jumps forward by more than ``max_jump`` s, the latest time
    before each fix): the live herd clock restarts at those fixes (``herd_time`` = the
    clock's latest time before the batch)."""
    finite = np.where(np.isfinite(stamp), stamp, -np.inf)
    before = np.maximum.accumulate(np.r_[herd_time, finite])[:-1]
    seen = np.isfinite(before)
    jumps = np.flatnonzero(seen & (finite > np.where(seen, before, 0.0) + max_jump)).tolist()
    return jumps, before
