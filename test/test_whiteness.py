"""Whiteness statistics against hand-computed formulas and known processes."""
import numpy as np
from scipy import stats

from herd_ros.estimation.whiteness import autocorrelation, whiteness


def test_autocorrelation_matches_direct_sum():
    x = np.random.default_rng(0).normal(size=200)
    xc = x - x.mean()
    direct = [np.sum(xc[k:] * xc[:len(x) - k]) / np.sum(xc * xc) for k in range(6)]
    np.testing.assert_allclose(autocorrelation(x, 5), direct, atol=1e-12)


def test_ljung_box_matches_hand_formula():
    x = np.random.default_rng(1).normal(size=300)
    w = whiteness(x, max_lag=10)
    xc = x - x.mean()
    n = len(x)
    rho = [np.sum(xc[k:] * xc[:n - k]) / np.sum(xc * xc) for k in range(1, 11)]
    q = n * (n + 2) * sum(r ** 2 / (n - k) for k, r in enumerate(rho, start=1))
    assert np.isclose(w.ljung_box, q)
    assert np.isclose(w.p_value, stats.chi2.sf(q, 10))


def test_white_noise_inside_band_ar1_outside():
    rng = np.random.default_rng(2)
    e = rng.normal(size=(20000, 2))
    white = whiteness(e)
    assert white.inside_90 > 0.8 and white.p_value > 1e-3
    ar = np.zeros_like(e)
    for t in range(1, len(e)):
        ar[t] = 0.9 * ar[t - 1] + e[t]
    red = whiteness(ar)
    assert red.inside_90 < 0.5 and red.ljung_box > 100 * white.ljung_box


def test_gaps_use_the_pairs_present():
    """With missing values (NaN) ρ̂_k is the mean lagged product over the pairs present over
    the mean square of the values present, times (m − k)/m (Parzen 1963), computed here by
    hand with loops."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=120)
    x[[0, 7, 8, 9, 50, 119]] = np.nan
    ok = np.isfinite(x)
    m = ok.sum()
    xc = x - x[ok].mean()
    c0 = np.nansum(xc * xc) / m
    direct = [1.0]
    for k in range(1, 6):
        prods = [xc[t] * xc[t - k] for t in range(k, len(x)) if ok[t] and ok[t - k]]
        direct.append(np.mean(prods) / c0 * (m - k) / m)
    np.testing.assert_allclose(autocorrelation(x, 5), direct, atol=1e-12)


def test_a_gap_does_not_make_a_series_white():
    """One missing step used to turn the mean into NaN and every lag into 0: a strongly
    autocorrelated series reported 100 % inside the band with Q = 0."""
    rng = np.random.default_rng(4)
    e = rng.normal(size=(5000, 2))
    ar = np.zeros_like(e)
    for t in range(1, len(e)):
        ar[t] = 0.9 * ar[t - 1] + e[t]
    ar[1000:1010] = np.nan
    red = whiteness(ar)
    assert red.n == 4990
    assert red.inside_90 < 0.5 and red.ljung_box > 1000 and red.p_value < 1e-6
    assert np.isnan(whiteness(np.full(10, np.nan)).inside_90)


def test_the_report_figure_takes_series_with_gaps_of_their_own(tmp_path):
    """Over gaps the velocity and the residual have different counts present, so their
    maximum lags differ (here 44 and 43): Fig. 4 draws each against its own lags."""
    from herd_ros.report.fit_figures import whiteness_figure
    rng = np.random.default_rng(5)
    vel, res = rng.normal(size=(200, 2)), rng.normal(size=(200, 2))
    vel[:23] = np.nan
    res[:26] = np.nan
    wv, wr = whiteness(vel), whiteness(res)
    assert (len(wv.acf), len(wr.acf)) == (45, 44)
    summary = {'agents': {'a': {'acf_velocity': wv.acf.tolist(), 'acf_residual': wr.acf.tolist(),
                                'whiteness_velocity': wv.as_dict(),
                                'whiteness_residual': wr.as_dict()}}}
    whiteness_figure(summary, tmp_path / 'fig4.png')
    assert (tmp_path / 'fig4.png').stat().st_size > 5_000
