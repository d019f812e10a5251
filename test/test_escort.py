"""A robot that waits for its animal's law escorts its animal (herd_ros/control/escort.py,
(E1), (E2)): checked by hand, against the lag of a first-order tracker of a ramp, and in a
loop that sees the robot late."""
import numpy as np
import pytest

from herd_ros.control.escort import escort_velocity, loop_lag


def test_the_escort_velocity_by_hand():
    robots = [[0.0, 0.0], [1.0, 1.0], [np.nan, np.nan], [2.0, 0.0]]
    animals = [[4.0, -2.0], [1.0, 1.0], [5.0, 5.0], [np.nan, 3.0]]
    v = escort_velocity(robots, animals, 2.0)
    # (a − p)/τ; a robot without odometry or an animal without a pose: 0
    assert np.allclose(v, [[2.0, -1.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    u = [[0.5, 0.0], [0.0, -0.25], [1.0, 1.0], [np.nan, 0.0]]
    w = escort_velocity(robots, animals, 2.0, u)
    # the animal's velocity fed forward where known
    assert np.allclose(w, [[2.5, -1.0], [0.0, -0.25], [0.0, 0.0], [0.0, 0.0]])
    with pytest.raises(ValueError):
        escort_velocity(robots, animals, 0.0)


def test_a_robot_catches_up_with_a_walking_animal():
    # an animal walking at 0.4 m/s, the robot 30 m behind, stepped at h = 0.1 s with τ = 5
    # s: without the feed-forward the robot settles v τ = 2 m behind (a first-order
    # tracker's lag on a ramp); with it the gap decays as e^{−t/τ} to nothing
    h, tau, speed = 0.1, 5.0, np.array([0.4, 0.0])
    for feed, lag in ((None, 2.0), (speed, 0.0)):
        p = np.array([[-30.0, 0.0]])
        for k in range(2000):                                     # 200 s = 40 τ
            a = speed * k * h
            p = p + h * escort_velocity(p, a[None], tau,
                                        None if feed is None else feed[None])
        gap = float(np.hypot(*(speed * 2000 * h - p[0])))
        assert gap == pytest.approx(lag, abs=0.05), (feed, gap)


def test_one_time_constant_per_robot_and_the_lag_by_hand():
    robots = [[0.0, 0.0], [0.0, 0.0]]
    animals = [[6.0, 0.0], [6.0, 0.0]]
    assert np.allclose(escort_velocity(robots, animals, [2.0, 3.0]), [[3.0, 0.0], [2.0, 0.0]])
    with pytest.raises(ValueError):
        escort_velocity(robots, animals, [2.0, 0.0])
    # the odometry's age (NaN: 0, never below 0) plus the time since the previous tick
    assert np.allclose(loop_lag([40.0, np.nan, -1.0], 25.0), [65.0, 25.0, 25.0])
    assert np.allclose(loop_lag([40.0], None), [40.0])
    assert np.allclose(loop_lag(None, 7.5), [7.5])


def delayed_escort(tau_of_lag, seconds=3600.0, start=50.0, delay=60.0, hold=30.0):
    """A robot escorting an animal that stands at the origin, in a loop that sees the
    robot ``delay`` s late and commands every ``hold`` s (the command held between ticks),
    integrated at 1 s; (E1) at τ = ``tau_of_lag(L)``, L = delay + hold. Returns the gap
    (m) at each second."""
    lag = delay + hold
    tau = tau_of_lag(lag)
    p = np.zeros((int(seconds) + 1, 2))
    p[0] = (start, 0.0)
    v = np.zeros((1, 2))
    for k in range(int(seconds)):
        if k % int(hold) == 0:
            seen = p[max(k - int(delay), 0)][None]
            v = escort_velocity(seen, [[0.0, 0.0]], tau)
        p[k + 1] = p[k] + v[0]
    return np.hypot(*p.T)


def test_a_late_loop_swings_at_the_herd_step_and_settles_at_its_lag():
    """Seen 60 s late and commanded every 30 s (L = 90 s, what the demo's controller had on
    a herd replayed at 1 400 ×), a robot at τ = 30 s (L/τ = 3, beyond the delayed loop's
    bound π/2) swings ever wider about an animal that stands still; at τ = max(30 s, L) it
    closes the 50 m gap and stays."""
    fast = delayed_escort(lambda lag: 30.0)
    assert fast[-600:].max() > 10 * 50.0
    slow = delayed_escort(lambda lag: max(30.0, lag))
    assert slow.max() < 1.5 * 50.0
    assert slow[-600:].max() < 1.0
