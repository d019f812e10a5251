"""Residuals shared by the herd: how much of what the law leaves unexplained is common motion.

The herd model of eq. 2 draws each animal's noise w_i independently. A herd that travels,
gathers and disperses together leaves a common part in the residuals that no per-animal law
captures, and it shows at long time scales first: summed over a window of W steps, the
residuals of two animals correlate more as W grows. For the standardised residuals
w̃_i^τ (each animal and axis scaled to unit variance) and block sums S_i^b = Σ_{τ ∈ b} w̃_i^τ
over B blocks of W steps, the herd's shared correlation at W is the mean over the pairs
i ≠ j of corr(S_i, S_j), computed in O(BN) from the block sums standardised per animal,
s_i = (S_i − S̄_i)/sd(S_i):

    r̄_W = (Var(Σ_i s_i) − N) / (N (N − 1))                                          (C1)

(per axis, then averaged; a block sums the residuals it has, one with none counts as the
mean). Independent noise
gives r̄_W ≈ 0 (± 1/√B); a common component c^τ of share ρ with lag-one autocorrelation φ
(w̃_i = √(1−ρ) ξ_i + √ρ c, c an AR(1) of unit variance) gives

    r̄_W = ρ S_W / ((1 − ρ) W + ρ S_W),     S_W = W + 2 Σ_{k=1}^{W−1} (W − k) φ^k      (C2)

which rises towards 1 with W when φ is near 1. On the steers (5 s steps, the law fitted on
the first 36 h, its residuals there) r̄ is 0.003 at one step, 0.027 at 1 min, 0.10 at
10 min and 0.20 at 1 h: the steers move together at the scale of hours. Fitting (C2) to
that curve gives ρ = 0.002, φ = 0.986 (τ ≈ 6 min); drawn in the free run, such a common
component moved the steers' spread from −30 to −28 % (5 seeds) — the gathering is not a
noise the law could add, so it is reported, not simulated.

Plain numpy; no ROS.
"""
from __future__ import annotations

import numpy as np

from herd_ros.nan_stats import empty_slices_quiet

#: window lengths (s) reported, those with at least :data:`MIN_BLOCKS` blocks in the data
WINDOWS_S = (60.0, 600.0, 3600.0)
#: fewest blocks for a window to be reported
MIN_BLOCKS = 20


def shared_correlation(residuals: np.ndarray, window: int) -> tuple[float, int]:
    """(r̄_W of (C1), the number of blocks) of ``residuals`` (T, N, 2) (NaN = missing) for
    blocks of ``window`` steps; NaN with fewer than two animals or blocks."""
    w = np.asarray(residuals, dtype=float)
    W = int(window)
    if w.ndim != 3 or w.shape[1] < 2 or W < 1:
        return float('nan'), 0
    B = len(w) // W
    if B < 2:
        return float('nan'), B
    with empty_slices_quiet():                      # an animal with no residual: NaN
        sd = np.nanstd(w, axis=0)                                       # (N, 2)
        z = (w - np.nanmean(w, axis=0)) / np.where(sd > 0, sd, np.nan)
    blocks = z[:B * W].reshape(B, W, w.shape[1], 2)
    present = np.isfinite(blocks).sum(axis=1)                           # (B, N, 2)
    sums = np.where(present > 0, np.nansum(blocks, axis=1), np.nan)
    values = []
    for axis in range(2):
        s = sums[:, :, axis]
        keep = np.isfinite(s).sum(axis=0) >= 2
        s = s[:, keep]
        if s.shape[1] < 2:
            continue
        s = s - np.nanmean(s, axis=0)
        sd_i = np.sqrt(np.nanmean(s ** 2, axis=0))
        s = np.nan_to_num(s[:, sd_i > 0] / sd_i[sd_i > 0])
        n = s.shape[1]
        if n < 2:
            continue
        total = np.mean(s.sum(axis=1) ** 2)
        own = np.sum(np.mean(s ** 2, axis=0))
        values.append((total - own) / (n * (n - 1)))
    return (float(np.mean(values)) if values else float('nan')), B


def common_component_correlation(rho: float, phi: float, window: int) -> float:
    """r̄_W of (C2) for a common AR(1) component of share ``rho`` and lag-one
    autocorrelation ``phi`` (the expectation :func:`shared_correlation` estimates)."""
    W = int(window)
    k = np.arange(1, W)
    s_w = W + 2.0 * np.sum((W - k) * float(phi) ** k)
    return float(rho * s_w / ((1.0 - rho) * W + rho * s_w))


def shared_residuals(residuals: list, dt: float, windows_s=WINDOWS_S) -> dict:
    """The herd's shared correlation (C1) of a model's residuals (a list of (T, N, 2)
    arrays, one per run, on the clock of step ``dt``) at one step and at each window of
    ``windows_s`` with at least :data:`MIN_BLOCKS` blocks: {'window_s': [...],
    'correlation': [...], 'blocks': [...]}. Runs are joined with a gap of one window."""
    out = {'window_s': [], 'correlation': [], 'blocks': []}
    runs = [np.asarray(r, dtype=float) for r in residuals if len(r)]
    if not runs:
        return out
    steps = [1] + sorted({int(round(s / dt)) for s in windows_s if s / dt > 1.5})
    for W in steps:
        gap = np.full((W, runs[0].shape[1], 2), np.nan)
        joined = np.concatenate([part for r in runs for part in (r, gap)])
        value, blocks = shared_correlation(joined, W)
        if blocks >= MIN_BLOCKS and np.isfinite(value):
            out['window_s'].append(float(W * dt))
            out['correlation'].append(value)
            out['blocks'].append(int(blocks))
    return out


def format_shared_residuals(result: dict) -> str:
    """One line: the shared correlation per window, and what a large one means."""
    if not result.get('window_s'):
        return 'residuals shared by the herd: too few data to say'
    cells = ', '.join(f'{_duration(w)} {c:+.3f}' for w, c in zip(result['window_s'],
                                                                  result['correlation']))
    line = (f'residuals shared by the herd (mean correlation between animals of the '
            f'residuals summed over a window; 0 = independent): {cells}')
    if max(result['correlation']) >= 0.1:
        line += ('\n  the herd moves together more than the law explains (its noise is drawn '
                 'independently per animal): expect the free run to miss some of the herd\'s '
                 'gathering and spreading')
    return line


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f'{seconds:g} s'
    if seconds < 7200:
        return f'{seconds / 60:g} min'
    return f'{seconds / 3600:g} h'
