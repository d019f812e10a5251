"""Radial bumps of a distance: the basis of the shared law's interaction profile
(:mod:`herd_ros.model.shared_law`) and of the alignment kernel (:mod:`herd_ros.model
.alignment`).

    ψ_b(d) = exp(−(d − r_b)² / 2s²) · ½(1 + cos(π d / r))   for d < r, 0 beyond

with r_b = r (b + ½)/B evenly in (0, r) and s = ⅔ r/B; the cosine taper makes a learned
function of distance vanish smoothly at the radius. Plain numpy.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from herd_ros.errors import HerdInputError

DEFAULT_RADIUS = 60.0
DEFAULT_PROFILE_SIZE = 6


@dataclass(frozen=True)
class DistanceProfile:
    """The radial basis ψ_b(d) of the shared law (module docstring)."""

    radius: float
    centers: tuple
    width: float

    def __post_init__(self):
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise HerdInputError(f'interaction radius must be positive, got {self.radius}')
        if len(self.centers) < 1 or not (np.isfinite(self.width) and self.width > 0):
            raise HerdInputError('the distance profile needs ≥ 1 centre and a positive width')

    @staticmethod
    def even(radius: float = DEFAULT_RADIUS, size: int = DEFAULT_PROFILE_SIZE):
        """B = ``size`` bumps evenly in (0, r), width ⅔ of their spacing."""
        if size < 1:
            raise HerdInputError(f'profile size must be ≥ 1, got {size}')
        spacing = float(radius) / size
        return DistanceProfile(float(radius), tuple(spacing * (np.arange(size) + 0.5)),
                               2.0 / 3.0 * spacing)

    @property
    def size(self) -> int:
        """Number of bumps B."""
        return len(self.centers)

    def features(self, distance) -> np.ndarray:
        """ψ_b(d): distances (...,) -> (..., B); zero at and beyond the radius."""
        d = np.asarray(distance, dtype=float)
        c = np.asarray(self.centers)
        taper = np.where(d < self.radius, 0.5 * (1.0 + np.cos(np.pi * np.minimum(
            d / self.radius, 1.0))), 0.0)
        return np.exp(-(d[..., None] - c) ** 2 / (2.0 * self.width ** 2)) * taper[..., None]

    def force(self, coefficients, distance) -> np.ndarray:
        """F(d) = Σ_b c_b ψ_b(d) (positive = attraction): (B,) × (...,) -> (...,)."""
        return self.features(distance) @ np.asarray(coefficients, dtype=float)
