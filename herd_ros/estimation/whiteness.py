"""Whiteness of a series: autocorrelation with white-noise bands and the Ljung–Box test.

If the model captured the predictable part of the motion, its residual w_i is white
(Schwager et al. 2007, §V, Fig. 4), while the velocity itself is strongly autocorrelated.

For a series x_t (t = 1..n) with sample autocorrelation

    ρ̂_k = Σ_{t=k+1}^{n} (x_t − x̄)(x_{t−k} − x̄) / Σ_t (x_t − x̄)²,      k = 1..L,

white noise has ρ̂_k ≈ N(0, 1/n), so the 100(1−α) % band is ±z_{1−α/2}/√n (90 %: 1.645/√n,
95 %: 1.960/√n). The Ljung–Box statistic (Ljung and Box 1978)

    Q = n (n + 2) Σ_{k=1}^{L} ρ̂_k² / (n − k)   ~  χ²_L under whiteness

gives a portmanteau p-value. For a 2-D series the components are tested separately and
combined: fractions averaged, Q summed (χ² with 2L degrees of freedom).

**Gaps.** A herd clock has missing steps (a collar stale, out of its span): NaN. The sums
then run over the pairs present (the amplitude-modulated series of Parzen 1963, "On
spectral analysis with missing observations and amplitude modulation", *Sankhyā A* 25;
Dunsmuir & Robinson 1981): with m values present, x̄ their mean and m_k the pairs
(x_t, x_{t−k}) both present,

    ρ̂_k = [Σ_pairs (x_t − x̄)(x_{t−k} − x̄) / m_k] / [Σ_present (x_t − x̄)² / m] · (m − k)/m,

which is the formula above when nothing is missing (m_k = n − k); n is then m in the bands
and in Q. A lag with no pair is NaN and left out of the fractions and Q. (Before, one NaN
made the mean NaN and the series looked perfectly white: every lag inside, Q = 0.)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

BANDS = {0.90: float(stats.norm.ppf(0.95)), 0.95: float(stats.norm.ppf(0.975))}


def _lagged_sums(x: np.ndarray, max_lag: int) -> np.ndarray:
    """Σ_t x_t x_{t−k} for k = 0..max_lag (via FFT, O(n log n))."""
    n = len(x)
    size = 1 << int(np.ceil(np.log2(max(2 * n - 1, 1))))
    f = np.fft.rfft(x, size)
    return np.fft.irfft(f * np.conj(f), size)[:max_lag + 1]


def autocorrelation(x: np.ndarray, max_lag: int) -> np.ndarray:
    """ρ̂_k for k = 0..max_lag of a 1-D series (via FFT, O(n log n)); NaN = a missing
    value (module docstring: gaps), a lag with no pair present NaN."""
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    m = int(ok.sum())
    if m == 0:
        return np.full(max_lag + 1, np.nan)
    xc = np.where(ok, x - x[ok].mean(), 0.0)
    acov = _lagged_sums(xc, max_lag)
    if acov[0] <= 0:
        return np.zeros(max_lag + 1)
    if m == len(x):
        return acov / acov[0]
    pairs = np.rint(_lagged_sums(ok.astype(float), max_lag))
    k = np.arange(max_lag + 1)
    with np.errstate(invalid='ignore', divide='ignore'):
        rho = (acov / pairs) / (acov[0] / m) * (m - k) / m
    return np.where(pairs > 0, rho, np.nan)


@dataclass
class Whiteness:
    """Whiteness summary of a (2-D) series."""

    lags: np.ndarray
    acf: np.ndarray             # (L+1, d) ρ̂_k per component, lag 0 included
    n: int
    inside_90: float            # fraction of lags 1..L inside the 90 % band (mean over comps)
    inside_95: float
    ljung_box: float            # Q summed over components
    ljung_box_dof: int
    p_value: float

    @property
    def band_90(self) -> float:
        """The 90 % white-noise band of a sample autocorrelation, ±1.645/√n."""
        return BANDS[0.90] / np.sqrt(self.n)

    @property
    def band_95(self) -> float:
        """The 95 % white-noise band of a sample autocorrelation, ±1.96/√n."""
        return BANDS[0.95] / np.sqrt(self.n)

    def as_dict(self) -> dict:
        """Plain types, for summary.json and the report."""
        return {'n': self.n, 'lags': int(self.lags[-1]), 'inside_90': self.inside_90,
                'inside_95': self.inside_95, 'ljung_box': self.ljung_box,
                'ljung_box_dof': self.ljung_box_dof, 'p_value': self.p_value}


def default_max_lag(n: int) -> int:
    """min(50, n/4): enough lags to see structure, few enough for a stable ρ̂."""
    return int(max(1, min(50, n // 4)))


def whiteness(series: np.ndarray, max_lag: int | None = None) -> Whiteness:
    """Autocorrelation, band fractions and Ljung–Box of ``series`` (n,) or (n, d)."""
    x = np.asarray(series, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    x = np.where(np.isfinite(x).all(axis=1)[:, None], x, np.nan)   # a step whole or missing
    n = int(np.isfinite(x[:, 0]).sum())                 # the values present (gaps: NaN)
    L = default_max_lag(n) if max_lag is None else int(max_lag)
    acf = np.column_stack([autocorrelation(x[:, c], L) for c in range(x.shape[1])])
    k = np.arange(1, L + 1)
    r = acf[1:]
    seen = np.isfinite(r) & (n > k)[:, None]
    if not seen.any():
        nan = float('nan')
        return Whiteness(lags=np.arange(L + 1), acf=acf, n=n, inside_90=nan, inside_95=nan,
                         ljung_box=nan, ljung_box_dof=0, p_value=nan)
    rs = np.abs(r[seen])
    inside90 = float((rs <= BANDS[0.90] / np.sqrt(n)).mean())
    inside95 = float((rs <= BANDS[0.95] / np.sqrt(n)).mean())
    with np.errstate(invalid='ignore', divide='ignore'):
        terms = n * (n + 2) * (r ** 2 / (n - k)[:, None])
    q = float(terms[seen].sum())
    dof = int(seen.sum())
    return Whiteness(lags=np.arange(L + 1), acf=acf, n=n, inside_90=inside90,
                     inside_95=inside95, ljung_box=q, ljung_box_dof=dof,
                     p_value=float(stats.chi2.sf(q, dof)))
