"""The last raw fix as a baseline of the skill tables for GPS input (issue 25)."""
import math

import numpy as np

from herd_ros.estimation.validation import last_raw_fix_rms
from herd_ros.trajectory import HerdTrajectory


def test_the_last_raw_fix_before_each_tick_predicts_the_next_tick_by_hand():
    times = np.arange(5.0)
    p = np.zeros((5, 1, 2))
    p[:, 0, 0] = [0.0, 1.0, 2.0, 3.0, 4.0]
    raw = {'a': (np.array([0.5, 2.2]), np.array([[1.0, 0.0], [5.0, 1.0]]))}
    run = HerdTrajectory(times, ['a'], p, meta={'raw_fixes': raw})
    # ticks 1, 2, 3 predict ticks 2, 3, 4 with the fixes of t 0.5, 0.5, 2.2:
    # errors (1 − 2, 0), (1 − 3, 0), (5 − 4, 1) -> squares 1, 4, 2
    got = last_raw_fix_rms([run], ['a'])
    assert math.isclose(got['a'], math.sqrt(7.0 / 3.0))
    assert math.isclose(got['herd'], math.sqrt(7.0 / 3.0))
    # a trajectory file has no raw fixes: no baseline
    assert last_raw_fix_rms([HerdTrajectory(times, ['a'], p)], ['a']) is None


def test_k_steps_ahead_the_naive_predictors_by_hand():
    """predict's baselines two steps ahead: p̂[t] from the origin t − 2 (and t − 3)."""
    from herd_ros.simulation.prediction import last_raw_fix_ahead, naive_ahead
    times = np.arange(6.0)
    p = np.zeros((6, 1, 2))
    p[:, 0, 0] = [0.0, 1.0, 3.0, 6.0, 10.0, 15.0]
    got = naive_ahead(p, 2)
    assert np.isnan(got['stay_put'][:3]).all() and np.isnan(got['constant_velocity'][:3]).all()
    # t = 3, 4, 5 from the origins 1, 2, 3: stay-put 1, 3, 6; constant velocity
    # p[o] + 2 (p[o] − p[o − 1]) = 1 + 2, 3 + 4, 6 + 6
    np.testing.assert_allclose(got['stay_put'][3:, 0, 0], [1.0, 3.0, 6.0])
    np.testing.assert_allclose(got['constant_velocity'][3:, 0, 0], [3.0, 7.0, 12.0])
    raw = {'a': (np.array([1.5, 2.0, 4.9]), np.array([[7.0, 0.0], [8.0, 0.0], [9.0, 0.0]]))}
    run = HerdTrajectory(times, ['a'], p, meta={'raw_fixes': raw})
    last = last_raw_fix_ahead(run, ['a'], 2)
    # origins 1, 2, 3: no fix yet at 1; the fix of t 2.0 (at the tick itself) at 2 and 3
    assert np.isnan(last[:4]).all()
    np.testing.assert_allclose(last[4:, 0, 0], [8.0, 8.0])
    assert last_raw_fix_ahead(HerdTrajectory(times, ['a'], p), ['a'], 2) is None
