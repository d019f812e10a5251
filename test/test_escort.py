"""A robot that waits for its animal's law escorts its animal (herd_ros/control/escort.py,
(E1)): checked by hand and against the lag of a first-order tracker of a ramp."""
import numpy as np
import pytest

from herd_ros.control.escort import escort_velocity


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
