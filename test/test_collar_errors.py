"""The collar error model, measured against a hand-made truth.

The truth is four agents on circles (known in closed form at any time), so the errors are
measured against positions this file computes itself, after converting the fixes back to ENU
with the project's exact geodesy (itself tested against pymap3d).
"""
import numpy as np
import pandas as pd
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.ingest.geodesy import geodetic_to_enu
from herd_ros.synthesis.collar_errors import (CollarErrorModel, simulate_collar_fixes,
                                              write_gps_csv)
from herd_ros.trajectory import HerdTrajectory

DATUM = (27.0153, -108.7937, 0.0)
T0 = 1_718_460_000.0
DURATION = 3 * 3600.0
RADIUS, OMEGA = 50.0, 0.01            # m, rad/s -> 0.5 m/s
CENTRES = np.array([[0.0, 0.0], [200.0, 0.0], [0.0, 200.0], [-300.0, -100.0]])
AGENTS = ['a', 'b', 'c', 'd']


def truth(agent_index, t):
    phase = OMEGA * (np.asarray(t) - T0) + agent_index
    return CENTRES[agent_index] + RADIUS * np.stack([np.cos(phase), np.sin(phase)], -1)


@pytest.fixture(scope='module')
def circles():
    times = T0 + np.arange(0.0, DURATION + 1.0)
    pos = np.stack([truth(i, times) for i in range(len(AGENTS))], axis=1)
    return HerdTrajectory(times, list(AGENTS), pos, meta={'datum': DATUM})


@pytest.fixture(scope='module')
def fixes(circles):
    return simulate_collar_fixes(circles, seed=11)


@pytest.fixture(scope='module')
def errors(fixes):
    """ENU errors of the status-0 fixes against the closed-form truth, and the multipath flag."""
    valid = fixes[fixes['status'] == 0]
    e, n, _ = geodetic_to_enu(valid['lat'].to_numpy(), valid['lon'].to_numpy(),
                              np.zeros(len(valid)), *DATUM)
    idx = valid['agent'].map({a: i for i, a in enumerate(AGENTS)}).to_numpy()
    true = np.empty((len(valid), 2))
    for i in range(len(AGENTS)):
        true[idx == i] = truth(i, valid['time'].to_numpy()[idx == i])
    return valid, np.column_stack([e, n]) - true, idx


def test_columns_and_order(fixes):
    for col in ('time', 'agent', 'lat', 'lon', 'alt', 'status', 'position_covariance_type',
                'cov_ee', 'cov_en', 'cov_nn'):
        assert col in fixes.columns
    assert (np.diff(fixes['time'].to_numpy()) >= 0).all()
    assert set(fixes['agent']) == set(AGENTS)
    assert set(fixes['status']) == {0, -1}


def test_noise_is_metre_level_and_correlated(errors):
    valid, err, idx = errors
    clean = ~valid['multipath'].to_numpy()
    std = err[clean].std(axis=0)
    assert ((std > 1.5) & (std < 4.0)).all(), std
    assert np.abs(err[clean].mean(axis=0)).max() < 1.0
    # slowly correlated: consecutive errors of one collar are alike
    for i in range(len(AGENTS)):
        e = err[(idx == i) & clean, 0]
        assert np.corrcoef(e[:-1], e[1:])[0, 1] > 0.6
    # the reported covariance is of the right size: E[err²/cov] ≈ 1 per axis
    ratio = (err[clean, 0] ** 2 / valid['cov_ee'].to_numpy()[clean]).mean()
    assert 0.5 < ratio < 1.6


def test_multipath_jumps_about_one_percent(errors):
    valid, err, _ = errors
    big = np.hypot(err[:, 0], err[:, 1]) > 15.0
    assert 0.004 < big.mean() < 0.02
    # the jumps are tens of metres, and they are what the flag marks
    assert np.hypot(err[big, 0], err[big, 1]).max() < 100.0
    flagged = valid['multipath'].to_numpy()
    assert (big == flagged).mean() > 0.995


def test_dropouts_and_irregular_intervals(fixes):
    expected = DURATION * len(AGENTS)
    missing = 1.0 - len(fixes) / expected
    assert 0.02 < missing < 0.12
    long_gaps = 0
    for agent, rows in fixes.groupby('agent'):
        dt = np.diff(rows['time'].to_numpy())
        assert (dt > 0).all()
        long_gaps += int((dt >= 60.0).sum())
        normal = dt[dt < 1.5]
        assert normal.std() > 0.01                       # jitter, not a clean 1 Hz
        assert ((dt > 1.5) & (dt < 2.5)).any()           # single skipped fixes
        assert abs(np.median(dt) - 1.0) < 0.05
    assert long_gaps >= 2


def test_no_fix_and_nan_altitude(fixes, errors):
    no_fix = fixes[fixes['status'] == -1]
    assert 0 < len(no_fix) < 0.01 * len(fixes)
    assert no_fix['alt'].isna().all()
    valid = fixes[fixes['status'] == 0]
    nan_alt = valid['alt'].isna()
    assert 0.002 < nan_alt.mean() < 0.03
    # NaN altitude never means NaN position
    assert np.isfinite(valid[['lat', 'lon']].to_numpy()).all()
    # a fix with status NO_FIX is far off: it must be rejected by status
    e, n, _ = geodetic_to_enu(no_fix['lat'].to_numpy(), no_fix['lon'].to_numpy(), 0.0, *DATUM)
    i = no_fix['agent'].map({a: k for k, a in enumerate(AGENTS)}).to_numpy()
    true = np.array([truth(k, t) for k, t in zip(i, no_fix['time'])])
    assert (np.hypot(e - true[:, 0], n - true[:, 1]) > 40.0).all()


def test_deterministic_for_a_seed(circles):
    short = circles.slice(0, 900)
    a = simulate_collar_fixes(short, seed=3)
    b = simulate_collar_fixes(short, seed=3)
    c = simulate_collar_fixes(short, seed=4)
    pd.testing.assert_frame_equal(a, b)
    assert len(a) != len(c) or not np.allclose(a['lat'], c['lat'])


def test_error_free_model_reproduces_truth(circles):
    exact = CollarErrorModel(horizontal_gm_std=0.0, horizontal_white_std=0.0,
                             vertical_gm_std=0.0, vertical_white_std=0.0, hdop_log_std=0.0,
                             multipath_fraction=0.0, skip_probability=0.0, outage_rate=0.0,
                             no_fix_probability=0.0, nan_alt_probability=0.0,
                             timing_jitter_std=0.0)
    fx = simulate_collar_fixes(circles.slice(0, 600), seed=0, model=exact)
    assert len(fx) == 599 * len(AGENTS)
    e, n, u = geodetic_to_enu(fx['lat'].to_numpy(), fx['lon'].to_numpy(),
                              fx['alt'].to_numpy(), *DATUM)
    i = fx['agent'].map({a: k for k, a in enumerate(AGENTS)}).to_numpy()
    true = np.array([truth(k, t) for k, t in zip(i, fx['time'])])
    # linear interpolation of a 0.5 m/s circle sampled at 1 Hz: < 3 mm chord error
    assert np.abs(e - true[:, 0]).max() < 5e-3 and np.abs(n - true[:, 1]).max() < 5e-3
    assert np.abs(u).max() < 1e-6


def test_write_gps_csv(tmp_path, fixes):
    path = write_gps_csv(fixes, tmp_path / 'gps.csv')
    text = path.read_text().splitlines()
    assert text[0] == 'time,agent,lat,lon,alt'
    back = pd.read_csv(path)
    valid = fixes[fixes['status'] == 0]
    assert len(back) == len(valid)
    np.testing.assert_allclose(back['lat'], valid['lat'], atol=1e-9)
    np.testing.assert_allclose(back['lon'], valid['lon'], atol=1e-9)
    np.testing.assert_allclose(back['time'], valid['time'], atol=1e-3)
    assert back['alt'].isna().sum() == valid['alt'].isna().sum()

    kept = pd.read_csv(write_gps_csv(fixes, tmp_path / 'all.csv', keep_no_fix=True))
    assert list(kept.columns) == ['time', 'agent', 'lat', 'lon', 'alt', 'status']
    assert len(kept) == len(fixes) and (kept['status'] == -1).sum() > 0


def test_bad_input(circles):
    bad = HerdTrajectory(circles.times[:10], list(AGENTS), circles.positions[:10].copy())
    bad.positions[3, 1, 0] = np.nan
    with pytest.raises(HerdInputError):
        simulate_collar_fixes(bad)
    with pytest.raises(HerdInputError):
        simulate_collar_fixes(circles.slice(0, 2), model=CollarErrorModel(fix_interval=5.0))
    with pytest.raises(HerdInputError):
        CollarErrorModel(multipath_fraction=1.5)
    with pytest.raises(HerdInputError, match='lat'):
        write_gps_csv(pd.DataFrame({'time': [0.0], 'agent': ['a']}), '/nonexistent/x.csv')
