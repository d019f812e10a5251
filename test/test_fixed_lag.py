"""The fixed-lag smoother (:func:`herd_ros.ingest.smoothing.fixed_lag_timeline`) and the
smoothers over a graze/walk mixture filter.

Independent expectations: with no lag it is the causal filter; with a lag as long as the
track, filterpy's RTS smoother; in between, on a known-truth track, its error lies
between the two. The mixture's prior moments against samples drawn from the mixture; the
RTS smoother over the default (fitted, mixture) ingest against the known truth.
"""
import numpy as np

from herd_ros.ingest.collar_filter import CollarFilter, process_noise, transition
from herd_ros.ingest.herd_clock import TimelineRecorder
from herd_ros.ingest.pipeline import trajectory_from_fixes
from herd_ros.ingest.smoothing import _moment_steps, fixed_lag_timeline, rts_timeline


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


def test_the_mixture_prior_has_the_moments_of_samples_drawn_from_it():
    """Two motion models taken with probabilities 0.8 / 0.2 over 60 s: the mean, the
    covariance and the covariance with the state of 400 000 draws."""
    rng = np.random.default_rng(3)
    x = np.array([2.0, -1.0, 0.3, -0.2])
    A = rng.normal(size=(4, 4))
    P = A @ A.T + np.eye(4)
    tau = 60.0
    comps = [(0.8, np.array([0.01]), np.array([300.0])), (0.2, np.array([0.1]), np.array([5.0]))]
    F, Q = _moment_steps(x[None], P[None], np.array([tau]), comps)
    n = 400_000
    x0 = rng.multivariate_normal(x, P, n)
    walk = rng.random(n) < 0.2
    x1 = np.empty_like(x0)
    for mask, (_, a, v) in ((~walk, comps[0]), (walk, comps[1])):
        Fj, Qj = transition(tau, v[0]), process_noise(tau, a[0], v[0])
        x1[mask] = x0[mask] @ Fj.T + rng.multivariate_normal(np.zeros(4), Qj, mask.sum())
    mean = F[0] @ x
    cov = F[0] @ P @ F[0].T + Q[0]
    cross = P @ F[0].T
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(x1.mean(0) - mean) < 5 * sd / np.sqrt(n))
    emp = np.cov(x1.T)
    assert np.allclose(emp, cov, rtol=0.02, atol=0.02 * sd.max() ** 2)
    emp_cross = (x0 - x0.mean(0)).T @ (x1 - x1.mean(0)) / (n - 1)
    assert np.allclose(emp_cross, cross, rtol=0.02, atol=0.02 * np.abs(cross).max())


def test_rts_over_the_default_mixture_filter_beats_it_on_a_known_track():
    """A collar walking east at 0.1 m/s, GPS fixes every second with 2 m noise, ingested
    with the defaults (each collar's model fitted, a graze/walk mixture): the RTS
    smoother's error is well below the causal filter's. (Smoothing with the last fitted
    model alone, as if the filter had no walk component, carried a velocity back over the
    whole track: 17 and 117 m off on two of these three seeds.)"""
    import pandas as pd

    from herd_ros.ingest.geodesy import enu_to_geodetic
    datum = (27.0, -108.8, 100.0)
    errs = {}
    for seed in range(3):
        rng = np.random.default_rng(seed)
        t = 1.7e9 + np.arange(300.0) + rng.uniform(0, 0.3, 300)
        z = np.stack([0.1 * (t - 1.7e9), np.zeros_like(t)], axis=1) \
            + rng.normal(0.0, 2.0, (300, 2))
        lat, lon, _ = enu_to_geodetic(z[:, 0], z[:, 1], 0.0, *datum)
        fixes = pd.DataFrame({'time': t, 'agent': 'cow', 'lat': lat, 'lon': lon,
                              'alt': datum[2]})
        for smoother in ('none', 'rts'):
            traj = trajectory_from_fixes(fixes, 2.0, datum=datum, smoother=smoother)
            pos = traj.positions[10:, 0]
            want = np.stack([0.1 * (traj.times[10:] - 1.7e9), np.zeros(len(pos))], axis=1)
            ok = np.isfinite(pos[:, 0])
            errs.setdefault(smoother, []).append(
                np.sqrt(np.mean(np.sum((pos[ok] - want[ok]) ** 2, axis=1))))
    causal, rts = np.mean(errs['none']), np.mean(errs['rts'])
    assert traj.meta['timelines']['cow'].walk is not None      # the mixture was smoothed
    assert rts < 0.7 * causal, errs
    assert rts < 0.3 * 2.0, errs
