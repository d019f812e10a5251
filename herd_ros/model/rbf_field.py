"""Gaussian radial-basis environment field g_i(p) of the herd model (Schwager et al. 2007, eq. 5).

    g_i(p) = Σ_k [θu_ik, θv_ik]ᵀ φ_k(p),   φ_k(p) = exp(−‖p − γ_k‖² / 2σ_k²) / (σ_k √(2π))

Centres γ_k sit at the cell centres of an even ``nx × ny`` grid over the region the herd
visited (or given bounds); every σ_k is 2/3 of the grid spacing (the mean of the x and y
spacings when they differ). A centre is kept only where the data visit its cell at least
``min_visits`` times, so the fitted field is made of bumps that sit over data: it decays to
zero away from the visited region instead of extrapolating (the paper prunes the same way).

The field is deliberately not a gradient: θu and θv are free, so herds can circulate.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.fit_defaults import DEFAULT_MIN_VISITS

try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is an install requirement
    def njit(*args, **kwargs):
        """numba's decorator where numba is absent: the function unchanged."""
        return (lambda f: f) if not args or not callable(args[0]) else args[0]

SQRT_2PI = float(np.sqrt(2.0 * np.pi))

#: Up to this many (step, agent, centre) terms the field is evaluated with numpy (a node's
#: tick), above it with the compiled loop (runs, simulations).
SMALL_FIELD_EVALUATION = 50_000



@dataclass(frozen=True)
class FieldGrid:
    """An even grid of RBF centres over ``bounds = (xmin, xmax, ymin, ymax)`` (metres)."""

    nx: int
    ny: int
    bounds: tuple[float, float, float, float]

    def __post_init__(self):
        if self.nx < 1 or self.ny < 1:
            raise HerdInputError(f'field grid must be at least 1x1, got {self.nx}x{self.ny}')
        xmin, xmax, ymin, ymax = self.bounds
        if not (np.isfinite(self.bounds).all() and xmax > xmin and ymax > ymin):
            raise HerdInputError(f'field bounds must satisfy xmin < xmax and ymin < ymax, '
                                 f'got {self.bounds}')

    @property
    def spacing(self) -> tuple[float, float]:
        """Cell width and height (m)."""
        xmin, xmax, ymin, ymax = self.bounds
        return (xmax - xmin) / self.nx, (ymax - ymin) / self.ny

    @property
    def sigma(self) -> float:
        """σ = 2/3 of the grid spacing (mean of the x and y spacings)."""
        sx, sy = self.spacing
        return (2.0 / 3.0) * 0.5 * (sx + sy)

    def centers(self) -> np.ndarray:
        """(nx·ny, 2) cell centres, x fastest."""
        xmin, xmax, ymin, ymax = self.bounds
        sx, sy = self.spacing
        cx = xmin + sx * (np.arange(self.nx) + 0.5)
        cy = ymin + sy * (np.arange(self.ny) + 0.5)
        gx, gy = np.meshgrid(cx, cy)
        return np.column_stack([gx.ravel(), gy.ravel()])

    def cell_visits(self, points: np.ndarray) -> np.ndarray:
        """How many of ``points`` (M, 2) fall in each cell (points outside count nowhere)."""
        xmin, xmax, ymin, ymax = self.bounds
        sx, sy = self.spacing
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        ix = np.floor((pts[:, 0] - xmin) / sx).astype(np.int64)
        iy = np.floor((pts[:, 1] - ymin) / sy).astype(np.int64)
        inside = (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
        flat = iy[inside] * self.nx + ix[inside]
        return np.bincount(flat, minlength=self.nx * self.ny)

    @staticmethod
    def over(points: np.ndarray, nx: int, ny: int, margin: float = 0.0) -> 'FieldGrid':
        """The grid over the bounding box of ``points`` (M, 2), widened by ``margin`` (m)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        lo = pts.min(axis=0) - margin
        hi = pts.max(axis=0) + margin
        span = np.maximum(hi - lo, 1e-6)
        hi = lo + span
        return FieldGrid(nx, ny, (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])))


@dataclass
class RbfBasis:
    """A set of Gaussian centres γ_k (K, 2) with widths σ_k (K,)."""

    centers: np.ndarray
    sigma: np.ndarray

    def __post_init__(self):
        self.centers = np.asarray(self.centers, dtype=float).reshape(-1, 2)
        self.sigma = np.broadcast_to(np.asarray(self.sigma, dtype=float),
                                     (len(self.centers),)).copy()

    @property
    def size(self) -> int:
        """Number of centres K."""
        return len(self.centers)

    def features(self, points: np.ndarray) -> np.ndarray:
        """φ_k(p) for ``points`` (..., 2) -> (..., K) (eq. 5 basis)."""
        pts = np.asarray(points, dtype=float)
        dx = pts[..., 0, None] - self.centers[:, 0]
        dy = pts[..., 1, None] - self.centers[:, 1]
        dx *= dx
        dy *= dy
        dx += dy
        dx *= -0.5 / self.sigma ** 2
        np.exp(dx, out=dx)
        dx *= 1.0 / (self.sigma * SQRT_2PI)
        return dx

    @staticmethod
    def from_grid(grid: FieldGrid, visits_of: np.ndarray | None = None,
                  min_visits: int = DEFAULT_MIN_VISITS) -> 'RbfBasis':
        """Centres of ``grid``; with ``visits_of`` (M, 2) only cells visited ≥ min_visits times."""
        centers = grid.centers()
        if visits_of is not None:
            keep = grid.cell_visits(visits_of) >= min_visits
            centers = centers[keep]
        return RbfBasis(centers, np.full(len(centers), grid.sigma))


def field_value(basis: RbfBasis, field_u: np.ndarray, field_v: np.ndarray,
                points: np.ndarray) -> np.ndarray:
    """g(p) = Σ_k [θu_k, θv_k] φ_k(p) for ``points`` (..., 2) -> (..., 2)."""
    phi = basis.features(points)
    return np.stack([phi @ np.asarray(field_u), phi @ np.asarray(field_v)], axis=-1)


def agent_fields(positions: np.ndarray, centers: np.ndarray, sigma: np.ndarray,
                 coef: np.ndarray, compiled: bool | None = None) -> np.ndarray:
    """g_i(p_i) for every agent from packed bases: positions (..., N, 2), centres (N, K, 2),
    σ (N, K), coefficients (N, K, 2) (unused slots 0) -> (..., N, 2).

    Compiled; a centre farther than 12 σ from the point adds nothing (φ < e⁻⁷² of its peak,
    below double precision next to any nearer centre), so a fine basis over a wide region
    costs what the centres near the agent cost. A NaN position gives NaN.

    ``compiled``: None chooses by size (numpy for one snapshot, so a live node never compiles
    at a tick); True forces the compiled loop (a simulation's many small steps)."""
    p = np.asarray(positions, dtype=float)
    flat = np.ascontiguousarray(p.reshape((-1,) + p.shape[-2:]))
    small = flat.shape[0] * centers.shape[0] * centers.shape[1] <= SMALL_FIELD_EVALUATION
    if not compiled and (compiled is False or small):
        # one snapshot (a node's tick): numpy, no compilation in a live node
        d2 = ((flat[..., :, None, :] - centers) ** 2).sum(-1)
        phi = np.exp(-d2 / (2.0 * sigma ** 2)) / (sigma * SQRT_2PI)
        return (phi[..., None] * coef).sum(-2).reshape(p.shape)
    out = _agent_fields(flat, np.ascontiguousarray(centers, dtype=float),
                        np.ascontiguousarray(sigma, dtype=float),
                        np.ascontiguousarray(coef, dtype=float))
    return out.reshape(p.shape)


@njit(cache=True)
def _agent_fields(p, centers, sigma, coef):  # pragma: no cover - compiled
    t_len, n, _ = p.shape
    k_len = centers.shape[1]
    out = np.zeros((t_len, n, 2))
    for t in range(t_len):
        for i in range(n):
            x = p[t, i, 0]
            y = p[t, i, 1]
            if not (np.isfinite(x) and np.isfinite(y)):
                out[t, i, 0] = np.nan
                out[t, i, 1] = np.nan
                continue
            gu = 0.0
            gv = 0.0
            for k in range(k_len):
                s = sigma[i, k]
                dx = x - centers[i, k, 0]
                dy = y - centers[i, k, 1]
                d2 = dx * dx + dy * dy
                if d2 > 144.0 * s * s:
                    continue
                phi = np.exp(-0.5 * d2 / (s * s)) / (s * SQRT_2PI)
                gu += phi * coef[i, k, 0]
                gv += phi * coef[i, k, 1]
            out[t, i, 0] = gu
            out[t, i, 1] = gv
    return out
