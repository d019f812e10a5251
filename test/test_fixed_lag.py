"""The fixed-lag smoother (:func:`herd_ros.ingest.smoothing.fixed_lag_timeline`).

Independent expectations: with no lag it is the causal filter; with a lag as long as the
track, filterpy's RTS smoother; in between, on a known-truth track, its error lies
between the two.
"""
import numpy as np

from herd_ros.ingest.collar_filter import CollarFilter
from herd_ros.ingest.herd_clock import TimelineRecorder
from herd_ros.ingest.smoothing import fixed_lag_timeline, rts_timeline


def grazing_track(seed, n=400):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(20.0, 60.0, n))
    v = np.cumsum(rng.normal(0.0, 0.02, (n, 2)), axis=0).clip(-0.3, 0.3)
    p = np.cumsum(v * np.diff(np.r_[0.0, t])[:, None], axis=0)
    return t, p, p + rng.normal(0.0, 3.0, p.shape)


def timeline_of(t, z):
    f = CollarFilter(accel_std=0.01, velocity_tau=300.0, default_position_std=3.0,
                     stale_after=1e6, reinit_after_gap=1e6)
    rec = TimelineRecorder(f)
    for tk, zk in zip(t, z):
        f.update(tk, *zk)
        rec.record()
    return rec.timeline()


def test_no_lag_is_the_filter_and_a_full_lag_the_rts_smoother():
    t, _, z = grazing_track(0, 120)
    tl = timeline_of(t, z)
    x0, P0 = fixed_lag_timeline(tl, 0)
    np.testing.assert_array_equal(x0, tl.x)
    xs, Ps = rts_timeline(tl)
    xl, Pl = fixed_lag_timeline(tl, len(tl.t))
    np.testing.assert_allclose(xl, xs, rtol=0, atol=1e-8)
    np.testing.assert_allclose(Pl, Ps, rtol=1e-8, atol=1e-10)
    # the last state has no future: every lag leaves it filtered
    np.testing.assert_allclose(fixed_lag_timeline(tl, 3)[0][-1], tl.x[-1])


def test_a_few_fixes_of_lag_recover_most_of_the_smoothing():
    errs = {0: [], 3: [], 'rts': []}
    for seed in range(3):
        t, p, z = grazing_track(seed)
        tl = timeline_of(t, z)
        truth = p[-len(tl.t):]
        for key in errs:
            x = rts_timeline(tl)[0] if key == 'rts' else fixed_lag_timeline(tl, key)[0]
            errs[key].append(np.sqrt(np.mean(np.sum((x[:, :2] - truth) ** 2, axis=1))))
    causal, lag3, rts = (np.mean(errs[k]) for k in (0, 3, 'rts'))
    assert rts < lag3 < causal
    assert (causal - lag3) > 0.5 * (causal - rts)      # most of the gain after 3 fixes
