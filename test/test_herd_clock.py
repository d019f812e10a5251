"""The herd clock: uniform ticks in data time; offline and streaming give the same snapshots."""
import numpy as np
import pytest

from herd_ros.ingest.collar_filter import CollarFilter, FilterParams
from herd_ros.ingest.collar_bank import CollarBank
from herd_ros.ingest.herd_clock import (BatchHerdClock, HerdClock, TimelineRecorder,
                                        resample_timelines, tick_grid)
from herd_ros.ingest.smoothing import gaussian_fir, gaussian_fir_taps, rts_on_ticks

AGENTS = ['a', 'b', 'c']
PARAMS = FilterParams(accel_std=0.1, stale_after=20.0)


def test_tick_grid_is_multiples_of_dt():
    ticks = tick_grid(1000.3, 1010.0, 2.5)
    np.testing.assert_allclose(ticks, [1002.5, 1005.0, 1007.5, 1010.0])
    assert tick_grid(0.1, 0.2, 1.0).size == 0
    np.testing.assert_allclose(np.diff(tick_grid(1.7e9 + 0.1, 1.7e9 + 3600, 0.2)), 0.2,
                               atol=1e-6)


def herd_fixes(seed=0):
    """Irregular stamps, a late starter (c), a dropout of b (stale), jumps, NO_FIX, NaN."""
    rng = np.random.default_rng(seed)
    fixes = []
    for i, agent in enumerate(AGENTS):
        t = 1000.0 + (15.0 if agent == 'c' else 0.0) + np.cumsum(rng.uniform(0.3, 2.0, 150))
        if agent == 'b':
            t = t[(t < 1060) | (t > 1120)]                 # 60 s silence > stale_after
        p = np.c_[10 * i + 0.2 * (t - 1000), 0.1 * (t - 1000)]
        z = p + rng.normal(0, 2.0, p.shape)
        status = np.zeros(len(t), int)
        jumps = rng.random(len(t)) < 0.05
        jumps[:3] = False
        z[jumps] += 60.0
        status[rng.random(len(t)) < 0.03] = -1
        z[rng.random(len(t)) < 0.03] = np.nan
        fixes += [(t[k], agent, z[k, 0], z[k, 1], status[k]) for k in range(len(t))]
    fixes.sort(key=lambda f: f[0])                        # arrival order = stamp order
    return fixes


def offline(fixes, dt):
    recs = {}
    for agent in AGENTS:
        f = CollarFilter(PARAMS)
        rec = TimelineRecorder(f)
        for t, a, e, n, s in fixes:
            if a == agent:
                f.update(t, e, n, status=s)
                rec.record()
        recs[agent] = rec.timeline()
    stamps = [f[0] for f in fixes]
    return resample_timelines(recs, tick_grid(min(stamps), max(stamps), dt), AGENTS), recs


def streaming(fixes, dt):
    filters = {a: CollarFilter(PARAMS) for a in AGENTS}
    clock = HerdClock(AGENTS, dt, PARAMS.stale_after)
    snaps, emitted_at = [], []
    for t, a, e, n, s in fixes:
        filters[a].update(t, e, n, status=s)
        new = clock.observe(a, t, filters[a])
        snaps += new
        emitted_at += [t] * len(new)
    snaps += clock.flush()
    return snaps, emitted_at


def batch_streaming(fixes, dt, batch, depth=8):
    """The node's path: a CollarBank and a BatchHerdClock fed ``batch`` fixes at a time."""
    bank = CollarBank(len(AGENTS), PARAMS)
    clock = BatchHerdClock(AGENTS, dt, PARAMS.stale_after, PARAMS.accel_std,
                           PARAMS.velocity_tau, depth=depth)
    snaps = []
    for s in range(0, len(fixes), batch):
        chunk = fixes[s:s + batch]
        t = np.array([f[0] for f in chunk])
        idx = np.array([AGENTS.index(f[1]) for f in chunk])
        e = np.array([f[2] for f in chunk])
        n = np.array([f[3] for f in chunk])
        status = np.array([f[4] for f in chunk])
        R = bank.measurement_covariances(np.zeros(len(chunk)), np.zeros((len(chunk), 9)))
        b = bank.process(idx, t, e, n, status, R)
        snaps += clock.observe(idx, t, b.accepted, b.x, b.P)
    return snaps + clock.flush()


@pytest.mark.parametrize('batch,depth', [(1, 8), (7, 2), (64, 8)])
def test_batch_clock_equals_offline(batch, depth, kernels):
    """Fixes one at a time or in batches (rings that must grow included): the snapshots of
    the offline resampling."""
    fixes = herd_fixes(1)
    traj, _ = offline(fixes, 2.5)
    snaps = batch_streaming(fixes, 2.5, batch, depth)
    np.testing.assert_array_equal([s.time for s in snaps], traj.times)
    np.testing.assert_allclose(np.array([s.positions for s in snaps]), traj.positions,
                               atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(np.array([s.position_cov for s in snaps]),
                               traj.meta['position_cov'], atol=1e-9, equal_nan=True)
    np.testing.assert_array_equal(np.array([s.stale for s in snaps]), traj.meta['stale'])
    np.testing.assert_array_equal(np.array([s.initialised for s in snaps]),
                                  traj.meta['initialised'])


@pytest.mark.parametrize('dt', [1.0, 2.5])
def test_offline_equals_streaming(dt):
    fixes = herd_fixes()
    traj, _ = offline(fixes, dt)
    snaps, emitted_at = streaming(fixes, dt)
    assert len(snaps) == len(traj.times)
    np.testing.assert_array_equal([s.time for s in snaps], traj.times)
    pos = np.array([s.positions for s in snaps])
    np.testing.assert_allclose(pos, traj.positions, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(np.array([s.position_cov for s in snaps]),
                               traj.meta['position_cov'], atol=1e-9, equal_nan=True)
    np.testing.assert_array_equal(np.array([s.stale for s in snaps]), traj.meta['stale'])
    np.testing.assert_array_equal(np.array([s.initialised for s in snaps]),
                                  traj.meta['initialised'])
    # the dropout of b shows as stale ticks, and only there
    b_stale = traj.meta['stale'][:, 1] & traj.meta['initialised'][:, 1]
    assert b_stale.any()
    b_last = max(t for t, a, *_ in fixes if a == 'b')
    in_gap = (traj.times > 1060 + PARAMS.stale_after - 2.5) & (traj.times <= 1120 + 2.5)
    after_end = traj.times > b_last + PARAMS.stale_after - 2.5
    assert np.all((in_gap | after_end)[b_stale])
    assert b_stale[in_gap & (traj.times > 1060 + PARAMS.stale_after + 2.5)
                   & (traj.times < 1118)].all()
    # c starts late: not initialised at the first ticks, then always
    assert not traj.meta['initialised'][0, 2] and traj.meta['initialised'][-1, 2]
    # snapshots are emitted in data time, never before their tick
    assert all(at >= s.time for at, s in zip(emitted_at, snaps))


def test_snapshot_waits_for_every_agent_or_staleness():
    clock = HerdClock(['a', 'b'], 1.0, stale_after=10.0)
    fa, fb = (CollarFilter(PARAMS, confirm_fixes_lost=1),
              CollarFilter(PARAMS, confirm_fixes_lost=1))
    fa.update(0.0, 0.0, 0.0)
    fb.update(0.0, 5.0, 0.0)
    assert [s.time for s in clock.observe('a', 0.0, fa)] == []       # b has not spoken
    assert [s.time for s in clock.observe('b', 0.0, fb)] == [0.0]
    out = []
    for k in range(1, 11):                                  # only a keeps reporting
        fa.update(float(k), 0.0, 0.0)
        out += clock.observe('a', float(k), fa)
    assert out == []                                        # b is silent but not stale yet
    fa.update(10.5, 0.0, 0.0)
    out = clock.observe('a', 10.5, fa)
    assert [s.time for s in out] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]
    # b carries its (constant-velocity) prediction up to stale_after ...
    assert out[0].positions[1] == pytest.approx([5.0, 0.0])
    assert not out[-1].stale[1] and out[-1].position_cov[1, 0, 0] > out[0].position_cov[1, 0, 0]
    # ... and is missing (NaN), never extrapolated, beyond it
    out = []
    for k in range(11, 25):             # the filter's stale_after is 20 s
        fa.update(float(k), 0.0, 0.0)
        out += clock.observe('a', float(k), fa)
    assert out[-1].time > 10.0 and out[-1].stale[1] and np.isnan(out[-1].positions[1]).all()
    assert np.isnan(out[-1].velocities[1]).all() and np.isfinite(out[-1].positions[0]).all()


def test_causal_estimate_ignores_later_fixes():
    fixes = herd_fixes(seed=3)
    traj, _ = offline(fixes, 1.0)
    cut = 1100.0
    later = [(t, a, e + 30.0 if t > cut else e, n, s) for t, a, e, n, s in fixes]
    traj2, _ = offline(later, 1.0)
    before = traj.times <= cut
    np.testing.assert_allclose(traj2.positions[before], traj.positions[before], atol=1e-12,
                               equal_nan=True)


def test_stationary_exact_fixes_give_the_position_at_every_tick():
    f = CollarFilter(PARAMS, position_std_floor=0.01, confirm_fixes_lost=1)
    rec = TimelineRecorder(f)
    cov = np.zeros(9)
    for t in np.arange(0.0, 20.0, 0.7):
        f.update(t, 3.0, -4.0, position_covariance=cov, position_covariance_type=3)
        rec.record()
    traj = resample_timelines({'a': rec.timeline()}, tick_grid(0.0, 19.6, 1.0))
    np.testing.assert_allclose(traj.positions[:, 0], np.tile([3.0, -4.0], (20, 1)), atol=1e-6)
    x, _ = rts_on_ticks(rec.timeline(), traj.times)
    np.testing.assert_allclose(x[:, :2], np.tile([3.0, -4.0], (20, 1)), atol=1e-6)


def test_rts_on_ticks_at_fix_times_equals_filterpy_rts():
    """At the fixes' own times the tick smoother is filterpy's RTS (independent code path)."""
    from filterpy.kalman import KalmanFilter
    from herd_ros.ingest.collar_filter import process_noise, transition
    rng = np.random.default_rng(4)
    f = CollarFilter(PARAMS)
    rec = TimelineRecorder(f)
    t = np.cumsum(rng.uniform(0.5, 1.5, 60))
    for tk in t:
        f.update(tk, *(rng.normal(0, 2, 2) + [0.3 * tk, 0]))
        rec.record()
    tl = rec.timeline()
    tau = np.concatenate([[0], np.diff(tl.t)])
    xs, Ps, _, _ = KalmanFilter(4, 2).rts_smoother(tl.x, tl.P, transition(tau),
                                                   process_noise(tau, PARAMS.accel_std))
    x, P = rts_on_ticks(tl, tl.t)
    np.testing.assert_allclose(x, xs, atol=1e-9)
    np.testing.assert_allclose(P, Ps, atol=1e-9)
    # between fixes the smoothed covariance is no larger than the filtered prediction's
    mid = 0.5 * (tl.t[:-1] + tl.t[1:])
    _, Pm = rts_on_ticks(tl, mid)
    assert np.all(np.trace(Pm[:, :2, :2], axis1=1, axis2=2) > 0)


def test_rts_timeline_is_filterpys_rts_segment_by_segment_compiled_or_not(monkeypatch):
    """Two filter segments (a re-initialisation between them): each smoothed on its own, as
    filterpy's RTS of that segment alone gives it (independent code), by the compiled
    backward pass and by the numpy loop used where the kernels are absent."""
    from filterpy.kalman import KalmanFilter
    from herd_ros.ingest import collar_bank
    from herd_ros.ingest.collar_filter import process_noise, transition
    from herd_ros.ingest.herd_clock import StateTimeline
    from herd_ros.ingest.smoothing import rts_timeline
    rng = np.random.default_rng(7)
    parts, expect = [], []
    start = 0.0
    for seg, n in enumerate((40, 25)):
        f = CollarFilter(PARAMS)
        rec = TimelineRecorder(f)
        t = start + np.cumsum(rng.uniform(0.5, 3.0, n))
        for tk in t:
            f.update(tk, *(rng.normal(0, 2, 2) + [0.2 * tk, -0.1 * tk]))
            rec.record()
        tl = rec.timeline()
        tau = np.concatenate([[0], np.diff(tl.t)])
        xs, Ps, _, _ = KalmanFilter(4, 2).rts_smoother(tl.x, tl.P, transition(tau),
                                                       process_noise(tau, PARAMS.accel_std))
        parts.append((tl, np.full(len(tl.t), seg)))
        expect.append((xs, Ps))
        start = t[-1] + 500.0
    joined = StateTimeline(np.concatenate([p[0].t for p in parts]),
                           np.concatenate([p[0].x for p in parts]),
                           np.concatenate([p[0].P for p in parts]), PARAMS.accel_std,
                           PARAMS.stale_after, np.concatenate([p[1] for p in parts]))
    want_x = np.concatenate([e[0] for e in expect])
    want_P = np.concatenate([e[1] for e in expect])
    for compiled in (True, False):
        if not compiled:
            monkeypatch.setattr(collar_bank, 'AVAILABLE', False)
        x, P = rts_timeline(joined)
        np.testing.assert_allclose(x, want_x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(P, want_P, rtol=1e-9, atol=1e-10)
    # a segment's last state has no future: it stays filtered
    last = len(parts[0][0].t) - 1
    np.testing.assert_array_equal(x[last], joined.x[last])
    assert not np.array_equal(x[last - 1], joined.x[last - 1])


def test_the_clock_without_compiled_kernels_gives_the_same_states(monkeypatch):
    """Timelines whose states carry different motion models (refitted collars): the numpy
    path (no kernels) predicts each state with its own model, as the compiled one does."""
    from herd_ros.ingest import collar_bank
    from herd_ros.ingest.herd_clock import StateTimeline, states_at
    rng = np.random.default_rng(3)
    tls = []
    for n in (30, 45):
        f = CollarFilter(PARAMS)
        rec = TimelineRecorder(f)
        for tk in np.cumsum(rng.uniform(0.5, 3.0, n)):
            f.update(tk, *(rng.normal(0, 2, 2) + [0.2 * tk, 0.0]))
            rec.record()
        tl = rec.timeline()
        K = len(tl.t)
        motion = np.column_stack([np.where(np.arange(K) < K // 2, 0.05, 0.3),
                                  np.where(np.arange(K) < K // 3, 0.0, 60.0)])
        tls.append(StateTimeline(tl.t, tl.x, tl.P, PARAMS.accel_std, PARAMS.stale_after,
                                 tl.segment, 0.0, motion))
    ticks = np.arange(0.0, 120.0, 0.7)
    compiled = states_at(tls, ticks)
    monkeypatch.setattr(collar_bank, 'AVAILABLE', False)
    numpy_only = states_at(tls, ticks)
    for a, b in zip(compiled, numpy_only):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_gaussian_fir_taps_and_response():
    b = gaussian_fir_taps()
    assert len(b) == 30 and b.sum() == pytest.approx(1.0)
    assert b[1] / b[0] == pytest.approx(np.exp(-1 / 72))    # exp(-j²/2σ²), σ = 6
    assert np.all(np.diff(b) < 0)
    # constant passes unchanged; a ramp is delayed by the group delay Σ j b_j
    const = np.full((50, 2, 2), 7.0)
    np.testing.assert_allclose(gaussian_fir(const), const)
    ramp = np.arange(100.0)
    delay = float(np.sum(np.arange(30) * b))
    np.testing.assert_allclose(gaussian_fir(ramp)[40:], ramp[40:] - delay, atol=1e-9)
    # causal: the output at t does not depend on the input after t
    x = np.random.default_rng(0).normal(size=80)
    y = x.copy()
    y[50:] += 100
    np.testing.assert_allclose(gaussian_fir(x)[:50], gaussian_fir(y)[:50])


def backlog_arrival(fixes, dt_wall=0.01):
    """The order a busy node takes a backlog in: one message per collar in turn, whatever
    its stamp; returns [(wall time, fix)], wall time advancing ``dt_wall`` per message."""
    queues = {a: [f for f in fixes if f[1] == a] for a in AGENTS}
    out, k = [], 0
    while any(queues.values()):
        for a in AGENTS:
            if queues[a]:
                out.append((k * dt_wall, queues[a].pop(0)))
                k += 1
    return out


def clock_on(arrivals, dt, grace_s):
    bank = CollarBank(len(AGENTS), PARAMS)
    clock = BatchHerdClock(AGENTS, dt, PARAMS.stale_after, PARAMS.accel_std,
                           PARAMS.velocity_tau, grace_s=grace_s)
    snaps = []
    for now, (t, a, e, n, status) in arrivals:
        idx = np.array([AGENTS.index(a)])
        R = bank.measurement_covariances(np.zeros(1), np.zeros((1, 9)))
        b = bank.process(idx, np.array([t]), np.array([e]), np.array([n]), np.array([status]),
                         R)
        snaps += clock.observe(idx, np.array([t]), b.accepted, b.x, b.P, now=now)
    return snaps, clock


def test_a_collar_whose_fixes_are_still_queued_is_waited_for_with_the_grace(kernels):
    """a reports every 5 s, b and c every second; taken one message per collar in turn (a
    backlog worked off), a runs ahead in data time. On data time alone b and c look silent
    and are NaN; with a grace of wall time they are waited for, and every pose is the
    offline one."""
    fixes = []
    for i, agent in enumerate(AGENTS):
        step = 5.0 if agent == 'a' else 1.0
        for t in np.arange(1000.0, 1300.0, step):
            fixes.append((t, agent, 3.0 * i + 0.01 * (t - 1000.0), 0.0, 0))
    fixes.sort(key=lambda f: f[0])
    traj, _ = offline(fixes, 2.5)
    arrivals = backlog_arrival(fixes)
    assert max(f[0] for _, f in arrivals[:60] if f[1] == 'a') > 1000 + 2 * PARAMS.stale_after
    hasty, _ = clock_on(arrivals, 2.5, grace_s=0.0)
    patient, clock = clock_on(arrivals, 2.5, grace_s=1.0)
    patient += clock.flush()
    stale_b = np.array([s.stale[1] for s in hasty])
    assert stale_b.mean() > 0.5                    # without the grace: b mostly missing
    np.testing.assert_array_equal([s.time for s in patient], traj.times)
    np.testing.assert_allclose(np.array([s.positions for s in patient]), traj.positions,
                               atol=1e-9, equal_nan=True)
    np.testing.assert_array_equal(np.array([s.stale for s in patient]), traj.meta['stale'])
    assert not np.array([s.stale for s in patient])[traj.times > 1005, 1:].any()


def test_a_collar_gone_quiet_is_silent_a_grace_later(kernels):
    """b stops at 1010 s; a goes on. The ticks past b's stale_after wait for the grace of
    wall time, then come with b missing (a poll without new fixes)."""
    bank = CollarBank(2, PARAMS)
    clock = BatchHerdClock(['a', 'b'], 1.0, PARAMS.stale_after, PARAMS.accel_std,
                           PARAMS.velocity_tau, grace_s=1.0)
    snaps = []

    def send(agent, t, now):
        idx = np.array([0 if agent == 'a' else 1])
        R = bank.measurement_covariances(np.zeros(1), np.zeros((1, 9)))
        b = bank.process(idx, np.array([t]), np.zeros(1), np.zeros(1), np.zeros(1, np.int64),
                         R)
        return clock.observe(idx, np.array([t]), b.accepted, b.x, b.P, now=now)

    for k in range(11):
        snaps += send('a', 1000.0 + k, now=0.01 * k)
        snaps += send('b', 1000.0 + k, now=0.01 * k)
    for k in range(11, 60):                          # b quiet; a's fixes arrive quickly
        snaps += send('a', 1000.0 + k, now=0.1 + 0.001 * k)
    last = snaps[-1].time
    assert last <= 1010.0 + PARAMS.stale_after      # waited for b (0.16 s of wall time)
    later = clock.poll(now=1.2)                      # b sent nothing for more than 1 s
    assert later and later[-1].time == 1058.0
    assert later[-1].stale[1] and np.isnan(later[-1].positions[1]).all()
    assert not later[-1].stale[0]
