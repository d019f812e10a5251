"""Wrong stamps in a file (issue 26: the live node's guards, offline too): a fix stamped in
the future is rejected as the node rejects it, a boot stamp 0 never stretches the clock, and
data time jumping by decades is one clear error instead of a clock of billions of ticks."""
import numpy as np
import pandas as pd
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.ingest.pipeline import trajectory_from_fixes
from herd_ros.ingest.stamp_guards import clock_jumps, future_stamps

T0 = 1.5e9          # 2017
NOW = 1.7e9         # the wall clock of the run (2023)


def herd(extra=None):
    rng = np.random.default_rng(0)
    rows = []
    for a in ('c1', 'c2'):
        t = T0 + np.arange(0, 3600, 60.0)
        rows.append(pd.DataFrame({'time': t, 'agent': a,
                                  'lat': 47 + rng.normal(0, 1e-5, len(t)),
                                  'lon': 8 + rng.normal(0, 1e-5, len(t))}))
    if extra is not None:
        rows.append(pd.DataFrame(extra))
    return pd.concat(rows, ignore_index=True)


def test_a_fix_from_the_future_is_rejected_and_counted():
    fixes = herd({'time': [NOW + 601.0], 'agent': ['c1'], 'lat': [47.0], 'lon': [8.0]})
    traj = trajectory_from_fixes(fixes, dt=60.0, now=NOW)
    assert traj.times[-1] <= T0 + 3600                      # the clock ends with the data
    assert traj.meta['counters']['c1']['rejected_future'] == 1
    assert traj.meta['counters']['c2']['rejected_future'] == 0
    outcomes = traj.meta['fix_outcomes']
    assert len(outcomes) == len(fixes) and outcomes[-1] == 'future'
    assert (outcomes == 'accepted').sum() >= 115             # nothing else lost
    # within max_stamp_ahead_s of the wall clock: an ordinary (late, lone) fix
    near = trajectory_from_fixes(herd({'time': [NOW + 599.0], 'agent': ['c1'],
                                       'lat': [47.0], 'lon': [8.0]}), dt=60.0, now=NOW)
    assert near.meta['fix_outcomes'][-1] != 'future'


def test_a_boot_stamp_never_stretches_the_clock():
    fixes = herd({'time': [0.0], 'agent': ['c2'], 'lat': [47.0], 'lon': [8.0]})
    traj = trajectory_from_fixes(fixes, dt=60.0, now=NOW)
    assert traj.times[0] >= T0 and traj.n_steps <= 61


def test_data_time_jumping_by_decades_is_one_clear_error():
    early = {'time': 1.0e9 + np.arange(5) * 60.0, 'agent': ['c3'] * 5,
             'lat': [47.0] * 5, 'lon': [8.0] * 5}        # consistent fixes: accepted
    with pytest.raises(HerdInputError, match='too long for one herd clock.*largest jump'):
        trajectory_from_fixes(herd(early), dt=1.0, now=NOW)


def test_the_guards_by_hand():
    assert future_stamps(np.array([99.0, 101.0]), 0.0, 100.0).tolist() == [False, True]
    jumps, before = clock_jumps(10.0, np.array([11.0, np.nan, 200.0, 201.0]), 100.0)
    assert jumps == [2] and before.tolist() == [10.0, 11.0, 11.0, 200.0]
