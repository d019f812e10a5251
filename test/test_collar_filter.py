"""Per-collar Kalman filter: accuracy on synthetic tracks, gating, rejection reasons, staleness."""
import numpy as np
import pandas as pd
import pytest
from filterpy.common import Q_discrete_white_noise

from herd_ros.errors import HerdInputError
from herd_ros.ingest.collar_filter import (CollarFilter, FilterParams, measurement_covariance,
                                           predict_state, process_noise)
from herd_ros.ingest.geodesy import enu_to_geodetic
from herd_ros.ingest.herd_clock import TimelineRecorder
from herd_ros.ingest.pipeline import trajectory_from_fixes
from herd_ros.ingest.smoothing import rts_on_ticks

NOISE = 3.0


def grazing_track(rng, n=3600, speed_std=0.15, tau_v=120.0):
    """1 Hz positions of a grazing animal: velocity an Ornstein-Uhlenbeck process (stationary
    std ``speed_std`` m/s per axis, correlation time ``tau_v`` s), i.e. an acceleration std
    of about speed_std·sqrt(2/tau_v) ≈ 0.02 m/s²."""
    a = np.exp(-1.0 / tau_v)
    v = np.zeros(2)
    p = np.zeros((n, 2))
    for k in range(1, n):
        v = a * v + np.sqrt(1 - a * a) * speed_std * rng.standard_normal(2)
        p[k] = p[k - 1] + v
    return np.arange(n, dtype=float), p


def noisy_with_jumps(rng, p, jump_rate=0.01, jump=50.0):
    z = p + NOISE * rng.standard_normal(p.shape)
    jumps = rng.random(len(p)) < jump_rate
    jumps[:3] = False                                    # the first fix initialises
    ang = rng.uniform(0, 2 * np.pi, len(p))
    z[jumps] += jump * np.c_[np.cos(ang), np.sin(ang)][jumps]
    return z, jumps


def run(f, t, z, **kw):
    rec = TimelineRecorder(f)
    est = np.full((len(t), 2), np.nan)
    reasons = []
    for k in range(len(t)):
        r = f.update(t[k], z[k, 0], z[k, 1], **kw)
        rec.record()
        reasons.append(r.reason)
        est[k] = f.x[:2] if f.initialised else np.nan
    return est, np.array(reasons), rec.timeline()


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_rmse_and_no_jump_passes(seed):
    rng = np.random.default_rng(seed)
    t, p = grazing_track(rng)
    z, jumps = noisy_with_jumps(rng, p)
    assert jumps.sum() > 20
    f = CollarFilter(accel_std=0.03, position_std_floor=0.5)
    cov = [NOISE**2, 0, 0, 0, NOISE**2, 0, 0, 0, 25.0]
    est, reasons, timeline = run(f, t, z, position_covariance=cov,
                                 position_covariance_type=2)
    # no jump passes the gates
    assert set(reasons[jumps]) <= {'speed', 'gate'}
    assert f.counters['rejected_gate'] + f.counters['rejected_speed'] >= jumps.sum()
    assert f.counters['reinitialised'] == 0
    # few genuine fixes are lost (the gate is at 99.9 %)
    assert (~np.isin(reasons[~jumps], ['accepted'])).mean() < 0.01
    raw_rmse = np.sqrt(np.mean((z[~jumps] - p[~jumps]) ** 2))
    assert abs(raw_rmse - NOISE) < 0.2
    rmse = np.sqrt(np.mean((est[10:] - p[10:]) ** 2))     # after the start-up transient
    assert rmse <= 0.40 * NOISE
    # the offline RTS smoother does much better still, evaluated between fixes
    xs, _ = rts_on_ticks(timeline, t[10:-1] + 0.5)
    mid = 0.5 * (p[10:-1] + p[11:])
    assert np.sqrt(np.mean((xs[:, :2] - mid) ** 2)) <= 0.25 * NOISE


def test_process_noise_is_filterpys_discrete_white_noise():
    for tau in (0.1, 1.0, 7.5):
        q = Q_discrete_white_noise(dim=2, dt=tau, var=0.3**2, block_size=2, order_by_dim=False)
        np.testing.assert_allclose(process_noise(tau, 0.3), q, rtol=1e-12, atol=1e-15)


def test_prediction_is_constant_velocity_with_growing_covariance():
    x = np.array([1.0, 2.0, 0.5, -0.25])
    P = np.diag([4.0, 4.0, 0.1, 0.1])
    xp, Pp = predict_state(x, P, 10.0, 0.1)
    np.testing.assert_allclose(xp, [6.0, -0.5, 0.5, -0.25])
    # position variance: 4 + 0.1·10² + 0.1²·10⁴/4 = 4 + 10 + 25
    assert Pp[0, 0] == pytest.approx(39.0)
    taus = np.array([1.0, 10.0, 100.0])
    _, Ps = predict_state(np.tile(x, (3, 1)), np.tile(P, (3, 1, 1)), taus, 0.1)
    assert np.all(np.diff(Ps[:, 0, 0]) > 0)


def test_measurement_covariance_by_type_and_floor():
    full = [4.0, 1.0, 0, 1.0, 9.0, 0, 0, 0, 30.0]
    np.testing.assert_allclose(measurement_covariance(full, 0, 5.0, 0.5), 25 * np.eye(2))
    np.testing.assert_allclose(measurement_covariance(full, 1, 5.0, 0.5), [[4, 1], [1, 9]])
    np.testing.assert_allclose(measurement_covariance(full, 3, 5.0, 0.5), [[4, 1], [1, 9]])
    np.testing.assert_allclose(measurement_covariance(full, 2, 5.0, 0.5), [[4, 0], [0, 9]])
    # zero, negative and NaN covariances are never trusted
    np.testing.assert_allclose(measurement_covariance(np.zeros(9), 3, 5.0, 0.5),
                               0.25 * np.eye(2))
    r = measurement_covariance([-1.0, 0, 0, 0, 1e-6, 0, 0, 0, 0], 2, 5.0, 0.5)
    np.testing.assert_allclose(r, 0.25 * np.eye(2))
    r = measurement_covariance([np.nan] * 9, 3, 5.0, 0.5)
    np.testing.assert_allclose(r, 25 * np.eye(2))
    # a singular full matrix: the small eigenvalue is floored, the large one kept
    r = measurement_covariance([4.0, 4.0, 0, 4.0, 4.0, 0, 0, 0, 0], 3, 5.0, 0.5)
    lam = np.linalg.eigvalsh(r)
    np.testing.assert_allclose(lam, [0.25, 8.0])


def test_zero_covariance_fix_does_not_freeze_the_filter():
    f = CollarFilter(accel_std=0.1, confirm_fixes_lost=1)
    zero = np.zeros(9)
    f.update(0.0, 0.0, 0.0, position_covariance=zero, position_covariance_type=3)
    np.testing.assert_allclose(f.P[:2, :2], 0.25 * np.eye(2))
    f.update(1.0, 1.0, 0.0, position_covariance=zero, position_covariance_type=3)
    assert f.x[0] > 0.3        # a second fix 1 m away moves the estimate substantially


def test_rejection_reasons_and_counters():
    f = CollarFilter()
    assert f.update(-1.0, 0.0, 0.0).reason == 'unconfirmed'   # a new track needs two fixes
    assert f.update(0.0, 0.0, 0.0).reason == 'accepted'
    assert f.update(1.0, 0.5, 0.0, status=-1).reason == 'no_fix'
    assert f.update(2.0, np.nan, 0.0).reason == 'nan'
    assert f.update(2.0, 0.0, np.inf).reason == 'nan'
    assert f.update(0.0, 0.0, 0.0).reason == 'time'         # equal stamp
    assert f.update(-5.0, 0.0, 0.0).reason == 'time'        # backwards
    assert f.update(3.0, 1.0, 1.0).reason == 'accepted'
    assert f.update(4.0, 200.0, 0.0).reason == 'speed'      # 200 m in 1 s
    assert f.t == 3.0
    assert f.counters == {'accepted': 2, 'rejected_no_fix': 1, 'rejected_nan': 2,
                          'rejected_time': 2, 'rejected_gate': 0, 'rejected_speed': 1,
                          'rejected_range': 0, 'rejected_unconfirmed': 1, 'reinitialised': 0}
    # STATUS_UNKNOWN (-2, Jazzy) is not NO_FIX: it is gated like any fix
    assert f.update(5.0, 1.0, 1.0, status=-2).accepted


def test_mahalanobis_gate_rejects_what_speed_allows():
    """A tight filter: 12 m off is allowed by speed (3 m/s × 10 s) but not by the gate."""
    f = CollarFilter(accel_std=0.01, default_position_std=1.0)
    for k in range(30):
        f.update(float(k), 0.0, 0.0)
    r = f.update(39.0, 12.0, 0.0)
    assert r.reason == 'gate' and r.mahalanobis2 > 13.8


def test_wrong_first_fix_never_starts_the_track():
    """A new track needs two consistent fixes: a lone outlier first is passed over."""
    rng = np.random.default_rng(5)
    t, p = grazing_track(rng, n=120)
    z = p + 2.0 * rng.standard_normal(p.shape)
    z[0] += [60.0, 0.0]                                     # a wrong first fix
    f = CollarFilter(accel_std=0.05)
    est, reasons, _ = run(f, t, z)
    assert list(reasons[:3]) == ['unconfirmed', 'unconfirmed', 'accepted']
    assert np.isnan(est[:2]).all() and np.hypot(*(est[2] - p[2])) < 8.0
    assert np.sqrt(np.mean((est[20:] - p[20:]) ** 2)) < 2.0


def test_wrong_track_is_left_after_reacquire_fixes():
    """A track that started on a consistent pair of outliers is left once the true fixes,
    beyond its reach, have lasted ``reacquire_fixes``."""
    f = CollarFilter(accel_std=0.05, reacquire_fixes=12)
    f.update(0.0, 500.0, 0.0)
    f.update(1.0, 500.0, 0.0)                                # confirmed, but wrong
    reasons = [f.update(2.0 + k, 0.0, 0.0).reason for k in range(12)]
    assert reasons == ['speed'] * 11 + ['reinitialised']
    assert np.hypot(*f.x[:2]) < 1.0


def test_a_chain_its_model_cannot_follow_is_adopted_at_its_last_place():
    """A lost track's confirming chain can span a move (within reach) that the collar's own
    slow model would follow only part of the way: three fixes a minute apart at the origin,
    then three at 400 m (300 s after the third: within reach, 3 m/s for 60 s then 1 m/s).
    Filtered through, the chain ends 44 m past its last fix with a velocity of 0.9 m/s that
    no fix shows, and the next fix at the same place fails the gate; the fix the chain's
    track so far cannot take (400 m where it predicts the origin within ~30 m) starts it
    afresh, so the track ends at 400 m at rest and takes the next fixes."""
    f = CollarFilter(accel_std=1e-4, velocity_tau=1e5, confirm_fixes_lost=6,
                     default_position_std=5.0)
    fixes = [(0.0, 0.0), (60.0, 0.0), (120.0, 0.0), (420.0, 400.0), (480.0, 400.0),
             (540.0, 400.0)]
    reasons = [f.update(t, e, 0.0).reason for t, e in fixes]
    assert reasons == ['unconfirmed'] * 5 + ['accepted']
    assert np.hypot(*(f.x[:2] - [400.0, 0.0])) < 1.0
    assert np.hypot(*f.x[2:]) < 0.05
    assert all(f.update(540.0 + 60.0 * k, 400.0, 0.0).reason == 'accepted'
               for k in range(1, 4))


def test_isolated_jumps_never_reinitialise():
    """Five jumps in a row in random directions are not a consistent track."""
    rng = np.random.default_rng(6)
    f = CollarFilter(accel_std=0.05)
    for k in range(20):
        f.update(float(k), *(rng.standard_normal(2)))
    for k in range(20, 30):
        ang = rng.uniform(0, 2 * np.pi)
        r = f.update(float(k), 80 * np.cos(ang) * (1 + k % 3), 80 * np.sin(ang))
        assert not r.accepted
    assert f.counters['reinitialised'] == 0
    assert np.hypot(*f.x[:2]) < 3


def test_dropout_makes_the_collar_stale_with_growing_covariance():
    f = CollarFilter(stale_after=30.0, confirm_fixes_lost=1)
    for k in range(10):
        f.update(float(k), 0.1 * k, 0.0)
    assert not f.is_stale(9.0) and not f.is_stale(39.0) and f.is_stale(39.5)
    var = [np.trace(f.estimate_at(t).P[:2, :2]) for t in (10.0, 30.0, 100.0, 1000.0)]
    assert np.all(np.diff(var) > 0)
    assert f.estimate_at(109.0).x[0] == pytest.approx(f.x[0] + 100 * f.x[2])
    # a fix after a gap longer than reinit_after_gap restarts the filter there
    # ... once confirmed by a second fix (a lone fix after a long gap may be an outlier)
    f2 = CollarFilter(stale_after=30.0)
    for k in range(10):
        f2.update(float(k), 0.1 * k, 0.0)
    assert f2.update(1000.0, 500.0, 500.0).reason == 'unconfirmed'
    r = f2.update(1001.0, 500.0, 500.0)
    assert r.reason == 'reinitialised' and abs(f2.x[0] - 500.0) < 1e-6


def test_bad_parameters_are_reported():
    with pytest.raises(HerdInputError, match='gate_probability'):
        FilterParams(gate_probability=1.5)
    with pytest.raises(HerdInputError, match='accel_std'):
        FilterParams(accel_std=-1.0)


def test_no_fix_and_nan_never_reach_the_output_and_nan_altitude_is_accepted():
    """Through the whole offline path: wild NO_FIX / NaN rows change nothing."""
    rng = np.random.default_rng(7)
    lat0, lon0 = 46.0, 7.0
    t, p = grazing_track(rng, n=600)
    z = p + NOISE * rng.standard_normal(p.shape)
    lat, lon, _ = enu_to_geodetic(z[:, 0], z[:, 1], 0.0, lat0, lon0, 500.0)
    clean = pd.DataFrame({'time': 1e9 + t, 'agent': 'cow', 'lat': lat, 'lon': lon,
                          'alt': np.nan})                   # no altitude at all
    bad_t = 1e9 + rng.choice(t[5:-5], 60, replace=False) + 0.5
    far_lat, far_lon, _ = enu_to_geodetic(5000.0, -3000.0, 0.0, lat0, lon0, 500.0)
    bad = pd.DataFrame({'time': bad_t, 'agent': 'cow',
                        'lat': np.where(np.arange(60) % 2, far_lat, np.nan),
                        'lon': np.where(np.arange(60) % 2, far_lon, 7.0),
                        'alt': 500.0, 'status': np.where(np.arange(60) % 2, -1, 0)})
    both = pd.concat([clean, bad]).sample(frac=1.0, random_state=1)   # any row order
    datum = (lat0, lon0, 500.0)
    ref = trajectory_from_fixes(clean, 1.0, datum=datum, accel_std=0.05)
    got = trajectory_from_fixes(both, 1.0, datum=datum, accel_std=0.05)
    c = got.meta['counters']['cow']
    assert c['accepted'] == 599 and c['rejected_unconfirmed'] == 1   # the first confirms
    assert c['rejected_no_fix'] == 30 and c['rejected_nan'] == 30
    np.testing.assert_array_equal(got.times, ref.times)
    np.testing.assert_allclose(got.positions, ref.positions, atol=1e-9)
    # and the datum is never taken from a NO_FIX row, even the earliest one
    early = pd.concat([pd.DataFrame({'time': [1e9 - 1], 'agent': ['cow'], 'lat': [far_lat],
                                     'lon': [far_lon], 'alt': [0.0], 'status': [-1]}), clean])
    auto = trajectory_from_fixes(early, 1.0, accel_std=0.05)
    assert auto.meta['datum'][:2] == (lat[0], lon[0]) and auto.meta['datum'][2] == 0.0
