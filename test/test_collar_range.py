"""A candidate far outside the range a collar has kept needs reacquire_fixes, not
confirm_fixes (FilterParams.range_*): a burst a few hundred metres off that is reachable in
the time never moves the track, a real move to a new place is followed after
reacquire_fixes fixes, and the compiled bank does the same fix by fix."""
import numpy as np
import pytest

from herd_ros.ingest.collar_bank import OUTCOMES, CollarBank
from herd_ros.ingest.collar_filter import CollarFilter, FilterParams, outside_range
from herd_ros.ingest.pipeline import DEFAULT_ACCEL_STD, DEFAULT_VELOCITY_TAU

pytestmark = pytest.mark.usefixtures('kernels')

GRAZE = 40          # fixes in the home range before the event
STEP = 240.0        # s between fixes: 330 m is within reach (3·60 + 1·180 m + the gate)


def grazing(seed=0, n=GRAZE):
    """A collar fixing every 4 minutes on an animal grazing about the origin (σ 8 m)."""
    rng = np.random.default_rng(seed)
    t = STEP * np.arange(n)
    return t, rng.normal(0.0, 8.0, (n, 2))


def burst_then_home(k=10, offset=(330.0, 0.0), seed=1):
    """Grazing, then ``k`` fixes scattered 10 m about a place ``offset`` away, then home."""
    rng = np.random.default_rng(seed)
    t, z = grazing(seed)
    tb = t[-1] + STEP * np.arange(1, k + 1)
    zb = np.asarray(offset) + rng.normal(0.0, 10.0, (k, 2))
    th = tb[-1] + STEP * np.arange(1, 6)
    zh = rng.normal(0.0, 8.0, (5, 2))
    return np.r_[t, tb, th], np.r_[z, zb, zh], GRAZE, GRAZE + k


def params(**given):
    """The ingest's default motion model (herd-ros ingest, the node)."""
    return FilterParams(accel_std=DEFAULT_ACCEL_STD, velocity_tau=DEFAULT_VELOCITY_TAU,
                        **given)


def run(params, t, z):
    f = CollarFilter(params)
    out = [f.update(s, e, n) for s, (e, n) in zip(t, z)]
    return f, out


def test_outside_range_by_hand():
    # four states at (±10, ±10): μ = 0, Σ = 100 I, + 1 m² I -> r = |d| / √101
    pts = np.array([[10, 10], [10, -10], [-10, 10], [-10, -10]], float)
    m = np.r_[4, pts.sum(0), (pts[:, 0] ** 2).sum(), (pts[:, 0] * pts[:, 1]).sum(),
              (pts[:, 1] ** 2).sum()]
    # 200 m east: r = 19.9 > 6, 200 − 3·√101 = 169.8 m beyond the range's 3 σ > 100 m
    assert outside_range(m, [200.0, 0.0], 6.0, 100.0, 4)
    assert not outside_range(m, [200.0, 0.0], 6.0, 100.0, 5)       # too few states yet
    assert not outside_range(m, [200.0, 0.0], 6.0, 180.0, 4)       # within the margin
    assert not outside_range(m, [50.0, 0.0], 6.0, 0.0, 4)          # r = 4.98 < 6
    assert not outside_range(m, [200.0, 0.0], 0.0, 100.0, 4)       # rule off


def test_a_reachable_burst_far_outside_the_range_never_moves_the_track():
    t, z, b0, b1 = burst_then_home()
    f, out = run(params(), t, z)
    assert not any(r.accepted for r in out[b0:b1])                # the burst: all refused
    assert {r.reason for r in out[b0:b1]} == {'range'}            # and said why
    assert f.counters['rejected_range'] == b1 - b0
    assert all(r.accepted for r in out[b1 + 1:])                  # home again: followed
    assert np.hypot(*f.x[:2]) < 30.0
    # without the range rule the same burst is adopted on its second fix
    _, plain = run(params(range_sigmas=0.0), t, z)
    assert plain[b0 + 1].reason == 'reinitialised'


def test_a_real_move_is_followed_after_reacquire_fixes():
    rng = np.random.default_rng(2)
    t, z = grazing(2)
    t2 = t[-1] + STEP * np.arange(1, 21)
    z2 = np.array([330.0, 0.0]) + rng.normal(0.0, 8.0, (20, 2))   # it stays there
    f, out = run(params(), np.r_[t, t2], np.r_[z, z2])
    moved = [k for k, r in enumerate(out) if r.reason == 'reinitialised']
    assert moved == [GRAZE + FilterParams().reacquire_fixes - 1]
    assert all(r.accepted for r in out[moved[0]:])
    assert np.hypot(*(f.x[:2] - [330.0, 0.0])) < 30.0


def test_after_a_move_far_outside_a_wide_range_the_new_place_is_followed():
    """A collar with a long record at home (300 fixes, 20 h) moves 330 m, within reach,
    and stays: the move is a jump chain (far outside the range) adopted on its
    ``reacquire_fixes``-th fix, and then every fix at the new place is taken. The range
    itself (301 states, one of them at the new place) still has the new place far
    outside it, so before the track's place counted as part of the range each later
    fix there began another chain (11 refused as 'range', the 12th adopted, and so on,
    the range growing by one state per chain); now the fixes taken there bring the new
    place into the range. The bank does the same fix by fix."""
    rng = np.random.default_rng(4)
    t, z = grazing(4, n=300)
    t2 = t[-1] + STEP * np.arange(1, 41)
    z2 = np.array([330.0, 0.0]) + rng.normal(0.0, 8.0, (40, 2))
    t, z = np.r_[t, t2], np.r_[z, z2]
    p = params()
    f = CollarFilter(p)
    out, far = [], []
    for s, (e, n) in zip(t, z):
        out.append(f.update(s, e, n))
        far.append(outside_range(f.range_moments, [330.0, 0.0], p.range_sigmas,
                                 p.range_margin, p.range_min_fixes))
    moved = 300 + FilterParams().reacquire_fixes - 1
    assert [r.reason for r in out[300:moved]] == ['range'] * (moved - 300)
    assert out[moved].reason == 'reinitialised'
    assert far[moved]             # one state of 301 there: the range has not taken it in
    assert not far[-1]            # the states taken there since have
    assert all(r.reason == 'accepted' for r in out[moved + 1:])
    assert np.hypot(*(f.x[:2] - [330.0, 0.0])) < 30.0
    bank = CollarBank(1, p)
    m = len(t)
    R = bank.measurement_covariances(np.zeros(m, np.int64), np.zeros((m, 9)))
    batch = bank.process(np.zeros(m, np.int64), t, z[:, 0], z[:, 1], np.zeros(m, np.int64), R)
    assert [OUTCOMES[c] for c in batch.outcome] == [r.reason for r in out]


def test_a_lost_track_does_not_restart_on_a_far_burst():
    t, z, b0, b1 = burst_then_home(k=8)
    t = t.copy()
    t[b0:] += 3600.0                                             # an hour of silence first
    f, out = run(params(), t, z)
    assert not any(r.accepted for r in out[b0:b1])
    assert all(r.reason == 'unconfirmed' for r in out[b0:b1])
    assert out[b1 + 1].accepted and np.hypot(*f.x[:2]) < 30.0


def test_a_far_fix_after_a_silence_does_not_confirm_a_chain_begun_at_home():
    """After an hour's silence (the track lost) one fix at home, then one 420 m off,
    within reach of it after 300 s: before, the far fix joined the home fix's chain and
    confirmed it, and the track started on the far fix (measured on the duty-cycled
    steers: a burst adopted so). A chain that a fix far outside the range joins is a jump
    chain: the far fix waits, and the next two fixes at home start the track there. The
    bank does the same fix by fix."""
    t, z = grazing(5)
    t0 = t[-1] + 3600.0
    t = np.r_[t, t0, t0 + 300.0, t0 + 360.0, t0 + 420.0]
    z = np.r_[z, [[3.0, -2.0], [420.0, 0.0], [-4.0, 5.0], [2.0, 1.0]]]
    p = params()
    f, out = run(p, t, z)
    assert [r.reason for r in out[GRAZE:]] == ['unconfirmed'] * 3 + ['reinitialised']
    assert np.hypot(*f.x[:2]) < 10.0
    _, before = run(params(range_sigmas=0.0), t, z)       # no range rule: taken
    assert before[GRAZE + 1].reason == 'reinitialised'
    bank = CollarBank(1, p)
    m = len(t)
    R = bank.measurement_covariances(np.zeros(m, np.int64), np.zeros((m, 9)))
    batch = bank.process(np.zeros(m, np.int64), t, z[:, 0], z[:, 1], np.zeros(m, np.int64), R)
    assert [OUTCOMES[c] for c in batch.outcome] == [r.reason for r in out]


def test_the_bank_does_the_same_fix_by_fix():
    cases = [burst_then_home(), burst_then_home(k=8, offset=(0.0, -900.0), seed=3)]
    p = params()
    bank = CollarBank(len(cases), p)
    for i, (t, z, _, _) in enumerate(cases):
        m = len(t)
        R = bank.measurement_covariances(np.zeros(m, np.int64), np.zeros((m, 9)))
        batch = bank.process(np.full(m, i), t, z[:, 0], z[:, 1], np.zeros(m, np.int64), R)
        _, ref = run(p, t, z)
        assert [OUTCOMES[c] for c in batch.outcome] == [r.reason for r in ref]
    assert bank.range_moments[:, 0].tolist() == [
        sum(r.accepted for r in run(p, t, z)[1]) for t, z, _, _ in cases]
