"""The live pace match (:mod:`herd_ros.control.pace_match`): robots whose law draws twice
their animals' noise are brought to their animals' speed in closed loop; robots already
at it keep factor 1; ticks without the animal count for nothing."""
import numpy as np
import pytest

from herd_ros.control.pace_match import PaceMatch

DT = 120.0          # the model's step (s)
TICK = 30.0         # the herd clock


def closed_loop(robot_noise, n_ticks=12000, seed=0, seen=None):
    """Animals and robots on the same AR(1) velocity law (damping 0.9 per tick), the
    robots' noise std ``robot_noise`` × the animals' × the match's factor; returns the
    match and the last 6 000 ticks' mean speeds at DT (animals, robots)."""
    rng = np.random.default_rng(seed)
    n = len(robot_noise)
    match = PaceMatch(n, DT)
    pa, ua, ur = (np.zeros((n, 2)) for _ in range(3))
    pr = np.zeros((n, 2))           # updated in place, as a node's latest odometry
    clock = np.zeros(n)
    hist_a, hist_r = [], []
    for k in range(n_ticks):
        ua = 0.9 * ua + 0.02 * rng.normal(size=(n, 2))
        ur = 0.9 * ur + 0.02 * (np.asarray(robot_noise) * match.factors)[:, None] \
            * rng.normal(size=(n, 2))
        pa = pa + TICK * ua
        pr += TICK * ur
        clock[:] = k * TICK
        a = pa.copy()
        if seen is not None:
            a[~seen(k)] = np.nan
        match.observe(k * TICK, a, clock, pr)
        hist_a.append(a)
        hist_r.append(pr.copy())
    lag = int(DT / TICK)
    A, R = np.array(hist_a[-6000:]), np.array(hist_r[-6000:])
    da = np.hypot(*(A[lag:] - A[:-lag]).transpose(2, 0, 1))
    seen_both = np.isfinite(da)
    va = np.where(seen_both, da, 0.0).sum(axis=0) / np.maximum(seen_both.sum(axis=0), 1) / DT
    vr = np.mean(np.hypot(*(R[lag:] - R[:-lag]).transpose(2, 0, 1)), axis=0) / DT
    return match, va, vr


def test_twice_the_noise_is_halved_and_the_speeds_meet():
    match, va, vr = closed_loop([2.0, 2.0, 0.5, 1.0])
    # the linear law's speed is proportional to its noise: the factor that matches is the
    # inverse of the excess (within the deadband and the samples' error)
    np.testing.assert_allclose(match.factors, [0.5, 0.5, 2.0, 1.0], rtol=0.15)
    np.testing.assert_allclose(vr, va, rtol=0.15)


def test_ticks_without_the_animal_count_for_nothing():
    # robot 0's animal is never seen; robot 1's only every other 500 ticks
    match, _, _ = closed_loop([2.0, 2.0], seen=lambda k: np.array([False, (k // 500) % 2 == 0]))
    assert match.factors[0] == 1.0
    assert match.factors[1] == pytest.approx(0.5, rel=0.15)


def test_repeated_or_older_ticks_are_ignored():
    match = PaceMatch(1, DT, min_samples=1, update_every=1)
    assert not match.observe(100.0, [[0.0, 0.0]], [100.0], [[0.0, 0.0]])
    assert not match.observe(100.0, [[5.0, 0.0]], [100.0], [[9.0, 0.0]])
    assert not match.observe(90.0, [[5.0, 0.0]], [90.0], [[9.0, 0.0]])
    assert len(match._ticks) == 1
    # one step of 120 s later, the robot 1.2 times as fast: its factor to 1 / 1.2
    assert match.observe(220.0, [[10.0, 0.0]], [220.0], [[12.0, 0.0]])
    assert match.factors[0] == pytest.approx(1 / 1.2)
    with pytest.raises(ValueError):
        PaceMatch(1, 0.0)
