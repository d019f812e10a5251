"""The ingest core of gps_ingest without ROS (issue 26): datum hold, stamp guards, clock
restarts, checked against hand-built streams."""
import math

import numpy as np

from herd_ros.ingest.collar_filter import STATUS_NO_FIX, FilterParams
from herd_ros.ingest.fix_stream import FixStream, clock_jumps, collar_frames, future_stamps
from herd_ros.io.cdr import NavSatFixes

LAT0, LON0 = 47.0, 8.0
M_PER_DEG_LAT = 111_195.0     # ~ at 47° (only relative sizes matter below)


def fixes(stamps, north_m=None, status=None):
    m = len(stamps)
    north_m = np.zeros(m) if north_m is None else np.asarray(north_m, float)
    return NavSatFixes([''] * m, np.asarray(stamps, float),
                       np.zeros(m, np.int64) if status is None else np.asarray(status),
                       LAT0 + north_m / M_PER_DEG_LAT, np.full(m, LON0), np.zeros(m),
                       np.zeros((m, 9)), np.zeros(m, np.int64))


def stream(**kw):
    params = FilterParams(stale_after=30.0, default_position_std=1.0)
    return FixStream(['a', 'b'], 1.0, params, **kw)


def test_datum_waits_for_every_collar_and_takes_the_earliest_valid_fix():
    s = stream()
    # collar 0: a NO_FIX at t=0 (never the datum), a valid fix 10 m north at t=1
    out = s.push(np.array([0, 0]), fixes([0.0, 1.0], [500.0, 10.0], [STATUS_NO_FIX, 0]), 0.0)
    assert s.datum is None and not out.odometry and s.fixes_waiting_for_datum == 2
    out = s.push(np.array([1]), fixes([0.5], [20.0]), 0.0)       # the other collar, earlier
    assert s.datum is not None and math.isclose(s.datum[0], LAT0 + 20.0 / M_PER_DEG_LAT)
    assert out.log[0][0] == 'info' and out.log[0][1].startswith('datum (first valid fix)')
    assert s.fixes_waiting_for_datum == 0
    assert s.counters(0)['rejected_no_fix'] == 1    # held fixes are processed, none lost


def test_datum_after_stale_after_when_a_collar_never_reports():
    s = stream()
    s.push(np.array([0]), fixes([0.0]), 0.0)
    s.push(np.array([0]), fixes([20.0]), 0.0)
    assert s.datum is None                          # 20 s < stale_after
    s.push(np.array([0]), fixes([31.0]), 0.0)
    assert s.datum is not None


def test_future_stamps_are_rejected_and_counted():
    s = stream(datum=(LAT0, LON0, 0.0), max_stamp_ahead_s=600.0)
    now = 1000.0
    s.push(np.array([0, 0, 1]), fixes([990.0, now + 601.0, 995.0]), now)
    assert s.rejected_future == {'a': 1, 'b': 0}
    assert s.clock.herd_time == 995.0               # the future stamp never reached it
    assert future_stamps(np.array([1.0, 2.0]), 0.0, 1.5).tolist() == [False, True]


def test_a_jump_of_data_time_restarts_the_clock():
    s = stream(datum=(LAT0, LON0, 0.0), max_clock_jump_s=100.0)
    t = [0.0, 1.0, 2.0, 5000.0, 5001.0]
    out = s.push(np.array([0, 1, 0, 0, 1]), fixes(t), 1e9)
    assert s.clock_restarts == 1
    assert any('herd clock restarted at 5000.000' in text for _, text in out.log)
    ticks = [snap.time for snap in out.snapshots]
    assert not [k for k in ticks if 10.0 < k < 4999.0]       # no tick of the gap
    jumps, before = clock_jumps(-math.inf, np.array(t), 100.0)
    assert jumps == [3] and before[3] == 2.0


def test_collar_frames_name_each_collar_three_ways():
    frames = collar_frames(['cow_1', 'cow_2'])
    assert frames['cow_2'] == frames['cow_2_gps'] == frames['cow_2/gps'] == 1


def test_a_quiet_collar_holds_the_clock_for_the_grace_then_a_poll_moves_it():
    s = stream(datum=(LAT0, LON0, 0.0), silence_grace_s=2.0)
    out = s.push(np.array([0, 1]), fixes([0.0, 0.0]), 100.0)
    ticks = []
    for k in range(1, 60):                          # b quiet; a's fixes within 1 s of wall
        ticks += [snap.time for snap in s.push(np.array([0]), fixes([float(k)]),
                                               100.0 + 0.01 * k).snapshots]
    assert max(ticks, default=0.0) < 1.0 + 30.0    # held: b might still be on its way
    assert not s.poll(101.5).snapshots              # 0.9 s since b's fix: still waiting
    late = s.poll(102.1).snapshots                  # 2.1 s: b is silent
    assert late and late[-1].time == 58.0 and math.isnan(late[-1].positions[1, 0])
    assert s.ticks == len(out.snapshots) + len(ticks) + len(late)
    # without the grace, data time alone: b is silent as soon as it is 30 s behind
    s0 = stream(datum=(LAT0, LON0, 0.0))
    s0.push(np.array([0, 1]), fixes([0.0, 0.0]), 100.0)
    got = [snap.time for k in range(1, 60)
           for snap in s0.push(np.array([0]), fixes([float(k)]), 100.0).snapshots]
    assert got[-1] == 58.0 and not s0.poll(200.0).snapshots
