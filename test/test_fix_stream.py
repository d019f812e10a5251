"""The ingest core of gps_ingest without ROS (issue 26): datum hold, stamp guards, clock
restarts, checked against hand-built streams."""
import math

import numpy as np
import pytest

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


# -- refits in the background (the node's batch timer) -------------------------------------
def fitted_stream(n, **kw):
    from herd_ros.ingest.pipeline import DEFAULT_WALK_ACCEL_STD, refit_config, with_walk
    params = with_walk(FilterParams(stale_after=60.0, default_position_std=3.0),
                       DEFAULT_WALK_ACCEL_STD)
    return FixStream([f'c{i}' for i in range(n)], 10.0, params, refit_config(params),
                     datum=(LAT0, LON0, 0.0), **kw)


def wandering_collars(n, k, seed=1):
    """(collars, fixes) of ``n`` collars wandering for ``k`` fixes each, 5-15 s apart,
    interleaved in stamp order; collar 1 has a burst 800 m off."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n):
        t = 1000.0 + np.cumsum(rng.uniform(5, 15, k))
        p = np.cumsum(rng.normal(0, 2, (k, 2)), 0) + rng.normal(0, 3, (k, 2))
        if i == 1:
            p[50:54] += 800.0
        rows += [(tt, i, x, y) for tt, (x, y) in zip(t, p)]
    rows.sort()
    t = np.array([r[0] for r in rows])
    xy = np.array([r[2:] for r in rows])
    m = len(t)
    return np.array([r[1] for r in rows]), NavSatFixes(
        [''] * m, t, np.zeros(m, np.int64), LAT0 + xy[:, 1] / M_PER_DEG_LAT,
        LON0 + xy[:, 0] / (M_PER_DEG_LAT * math.cos(math.radians(LAT0))), np.zeros(m),
        np.zeros((m, 9)), np.zeros(m, np.int64))


def pushed(s, collars, fx, sizes, collect_every=0):
    """Push the fixes in batches of ``sizes`` (cycled); every state put out, and every
    snapshot (time, positions) — after collecting every refit and flushing the clock."""
    from herd_ros.io.cdr import take_fixes
    states, snaps = {}, []

    def take(out):
        for idx, stamp, x, _ in out.odometry:
            for i, t, row in zip(idx.tolist(), stamp.tolist(), x.tolist()):
                states[i, t] = row
        snaps.extend((sn.time, sn.positions) for sn in out.snapshots)

    k = j = 0
    while k < len(collars):
        sel = np.arange(k, min(k + sizes[j % len(sizes)], len(collars)))
        take(s.push(collars[sel], take_fixes(fx, sel), 100.0 + j))
        j += 1
        k = sel[-1] + 1
        if collect_every and j % collect_every == 0:
            take(s.collect(100.0 + j))
    take(s.collect(100.0 + j, wait=True))
    snaps.extend((t, p) for t, p in ((sn.time, sn.positions) for sn in s.clock.flush()))
    return states, snaps


@pytest.mark.parametrize('lag', [0.0, 60.0, 400.0])
def test_refits_in_the_background_give_the_synchronous_states_and_snapshots(lag):
    # the synchronous stream is the offline path's (test_gps_ingest_node); in the background
    # every fix must still be filtered by the model its collar had at that fix offline
    collars, fx = wandering_collars(5, 120)
    ref = fitted_stream(5)
    ref.refitter.config.lag_s = lag
    ref_states, ref_snaps = pushed(ref, collars, fx, [7])
    assert len(ref_states) > 500 and len(ref_snaps) > 100
    for sizes, every, chunk in (([7, 1, 30, 3], 3, 256), ([1], 1, 256), ([400], 0, 256),
                                ([400], 0, 1)):
        s = fitted_stream(5, refit_in_background=True)
        s.refitter.config.lag_s = lag
        s.background.max_collars = chunk        # 1: the refits due together, one by one
        states, snaps = pushed(s, collars, fx, sizes, every)
        assert states == ref_states, (sizes, chunk)
        assert s.refitter.refits == 15 and s.fixes_held_for_refits == 0
        assert [t for t, _ in snaps] == [t for t, _ in ref_snaps]
        assert all(np.array_equal(a, b, equal_nan=True)
                   for (_, a), (_, b) in zip(snaps, ref_snaps))


def test_a_refit_in_the_background_holds_only_the_fixes_that_need_its_model(monkeypatch):
    """A refit takes over ``lag_s`` of data time after its point: meanwhile its collar's
    fixes are filtered by the old model; from its first fix stamped that late on, its
    fixes wait for the refit; the other collar's are filtered."""
    import threading

    from herd_ros.ingest.motion_refit import RefitJob
    release, started = threading.Event(), threading.Event()
    run = RefitJob.run

    def slow(job):
        started.set()
        assert release.wait(30)
        return run(job)

    monkeypatch.setattr(RefitJob, 'run', slow)
    from herd_ros.io.cdr import take_fixes
    collars, fx = wandering_collars(2, 60)
    keep = (collars == 0) | (np.cumsum(collars == 1) % 2 == 0)   # collar 1 at half the rate
    collars, fx = collars[keep], take_fixes(fx, keep)
    s = fitted_stream(2, refit_in_background=True)
    s.refitter.config.lag_s = lag = 60.0      # a large herd's (6 ms per collar)
    # the first refit is due after a collar's 20th fix: collar a reaches it first, b later
    twentieth = [int(np.flatnonzero(np.cumsum(collars == i) == 20)[0]) for i in (0, 1)]
    a = int(np.argmin(twentieth))
    b = 1 - a
    s.push(collars[:twentieth[a] + 1], take_fixes(fx, np.arange(twentieth[a] + 1)), 100.0)
    assert started.wait(30) and s.background.pending[a] and not s.background.pending[b]
    # the next fixes, up to b's own refit point
    nxt = np.arange(twentieth[a] + 1, twentieth[b])
    out = s.push(collars[nxt], take_fixes(fx, nxt), 101.0)
    own = collars[nxt] == a
    needs = own & (fx.stamp[nxt] >= fx.stamp[twentieth[a]] + lag)   # a's new model's fixes
    assert needs.any() and (own & ~needs).any() and (~own).any()
    got = np.concatenate([idx for idx, *_ in out.odometry])
    assert s.fixes_held_for_refits == needs.sum()
    assert (got == a).sum() == (own & ~needs).sum()          # before the take-over: filtered
    assert (got == b).sum() == (~own).sum()                   # b: every fix accepted
    assert s.clock.waiting[a] and not s.clock.waiting[b]
    held_from = fx.stamp[nxt][needs].min()
    assert all(sn.time <= held_from for sn in out.snapshots)   # no tick past a waiting fix
    release.set()
    rest = s.collect(102.0, wait=True)
    assert s.fixes_held_for_refits == 0 and not s.clock.waiting.any()
    assert (np.concatenate([idx for idx, *_ in rest.odometry]) == a).sum() == needs.sum()


def test_finished_refits_let_go_of_their_windows():
    """A refit due while its collar's previous one is still queued starts from that one's
    result (a link to it); once fitted, neither may keep the other, nor its windows, alive
    (a chain of them would hold every window ever fitted: memory growing with the refits,
    over days)."""
    import gc
    import threading
    import weakref

    from herd_ros.ingest.motion_refit import RefitJob
    jobs, release = [], threading.Event()
    run = RefitJob.run

    def held(job):
        jobs.append(weakref.ref(job))
        assert release.wait(30)           # every refit waits: the later ones queue behind
        return run(job)

    RefitJob.run = held
    try:
        collars, fx = wandering_collars(3, 200)
        s = fitted_stream(3, refit_in_background=True)
        s.refitter.config.lag_s = 1e6      # no model needed yet: nothing waits for them
        from herd_ros.io.cdr import take_fixes
        s.push(collars, take_fixes(fx, np.arange(len(collars))), 100.0)
        queued = [j for j in s.background._queued]
        linked = [x for j in queued for x in j.start if type(x).__name__ == 'ScheduledFit']
        assert linked                      # the later refits start from the earlier ones
        del queued, linked
        release.set()
        s.collect(101.0, wait=True)
    finally:
        RefitJob.run = run
        release.set()
    gc.collect()
    assert s.refitter.refits >= 3 * 3 and len(jobs) >= 3
    alive = [r() for r in jobs if r() is not None]
    # what may stay: the jobs of the models still waiting to take over, without windows
    waiting = {id(e.job) for q in s.refitter.scheduled for e in q}
    assert all(id(j) in waiting for j in alive), (len(alive), len(waiting))
    assert all(j.windows is None and not any(type(x).__name__ == 'ScheduledFit'
                                             for x in j.start) for j in alive)
