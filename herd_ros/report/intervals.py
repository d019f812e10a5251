"""Confidence intervals of the reports (plain math; no numpy needed)."""
from __future__ import annotations

import math

#: the standard normal quantile of a two-sided 95 % interval
Z95 = 1.959963984540054


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson's score interval of a binomial proportion (Wilson 1927, JASA 22:209; 95 % by
    default): ``(p + z²/2n ± z √(p(1−p)/n + z²/4n²)) / (1 + z²/n)``."""
    if n <= 0:
        return (0.0, 1.0)
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # at 0 and n the bounds are exactly 0 and 1 (not a rounding away from them)
    return (0.0 if successes == 0 else max(0.0, centre - half),
            1.0 if successes == n else min(1.0, centre + half))
