"""A collar silent in the scored data gives NaN for that animal — the answer — and no numpy
warning on the user's terminal (herd_ros.nan_stats)."""
import warnings

import numpy as np

from herd_ros.estimation.validation import damping_only_rms
from herd_ros.simulation.free_run import shape_and_pace
from herd_ros.simulation.prediction import _rms
from herd_ros.trajectory import HerdTrajectory


def test_an_absent_animal_is_nan_without_warnings():
    rng = np.random.default_rng(0)
    p = np.cumsum(rng.normal(0, 1, (200, 3, 2)), axis=0)
    train = HerdTrajectory(np.arange(200.0), ['a', 'b', 'c'], p)
    q = p.copy()
    q[:, 2] = np.nan                                  # 'c' silent throughout the held-out run
    test = HerdTrajectory(np.arange(200.0), ['a', 'b', 'c'], q)
    with warnings.catch_warnings():
        warnings.simplefilter('error')                # any warning fails the test
        out = damping_only_rms([train], [test], ['a', 'b', 'c'])
        stats = shape_and_pace(q, 1.0)
        rms = _rms(np.full((5, 2), np.nan))
    assert np.isnan(out['c']) and np.isfinite(out['a']) and np.isfinite(out['herd'])
    assert np.isnan(stats['pace'][2]) and np.isfinite(stats['pace'][:2]).all()
    assert np.isnan(rms)
