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


def test_a_lost_track_does_not_restart_on_a_far_burst():
    t, z, b0, b1 = burst_then_home(k=8)
    t = t.copy()
    t[b0:] += 3600.0                                             # an hour of silence first
    f, out = run(params(), t, z)
    assert not any(r.accepted for r in out[b0:b1])
    assert all(r.reason == 'unconfirmed' for r in out[b0:b1])
    assert out[b1 + 1].accepted and np.hypot(*f.x[:2]) < 30.0


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
