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
