"""The safety layer every controller mode goes through: speed, fence, obstacles, stale data.

All functions take world-frame arrays of N robots: positions p (N, 2) m, velocities v
(N, 2) m/s, and a horizon h (s) over which a command is assumed to be held (the controller
period, or longer to cover a controller that dies — the robot keeps its last command until
``cmd_timeout_s``). The guarantees, in order of application (:func:`safe_velocity`):

1. **Speed**: ‖v‖ ≤ v_max (the direction is kept).
2. **Fence** (a simple polygon, convex or not): a robot inside never gets a command whose
   straight path p → p + h v crosses the fence. A velocity heading out is first projected
   onto the edge it would hit (the outward normal component is removed beyond the
   ``margin``, so the robot slides along the fence), then scaled down along its direction
   so the path stops ``margin`` metres (along the path) short of the first crossing::

       s = min(1, max(t* (L + m) − m, 0) / L),   L = h ‖v‖,

   where t* ∈ [0, 1] is the first crossing of the segment p → p + (L + m) v̂ with an edge.
   The scaling step alone gives the guarantee (no crossing ⇒ still inside); the projection
   only keeps robots moving. A robot found outside may only move toward the nearest point of
   the fence (the component of v along that direction, never away).
3. **Obstacles** (circles x, y, r): the same two steps for the inflated discs r + margin —
   the inward radial component is removed where the path would enter a disc, then the path
   is shortened to stop before the disc.
4. **Stale data**: :func:`stale_mask` says which robots have no odometry newer than a timeout;
   the controller commands zero for them.

Why by hand: segment/polygon intersection is a few vectorised lines (matplotlib's ``Path``
answers containment, used here, but not "where does this segment first cross"), and shapely
is not a dependency of the package.
"""
from __future__ import annotations

import numpy as np
from matplotlib.path import Path

from herd_ros.control.kinematics import limit_norm
from herd_ros.errors import HerdInputError


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _norm(v):
    return np.sqrt((np.asarray(v) ** 2).sum(-1))


def limit_speed(velocity: np.ndarray, max_speed: float) -> np.ndarray:
    """‖v_i‖ ≤ v_max for each row of (N, 2), direction kept."""
    return limit_norm(velocity, max_speed)


def stale_mask(last_seen: np.ndarray, now: float, timeout: float) -> np.ndarray:
    """True where the last message (s, NaN = never) is older than ``timeout`` at ``now``."""
    last = np.asarray(last_seen, dtype=float)
    with np.errstate(invalid='ignore'):
        return ~(now - last <= timeout)


def polygon_from_flat(values, name: str = 'fence') -> np.ndarray | None:
    """[x1, y1, x2, y2, ...] -> (M, 2) vertices; empty -> None (no fence)."""
    flat = np.asarray(list(values), dtype=float).ravel()
    if flat.size == 0:
        return None
    if flat.size % 2 or flat.size < 6:
        raise HerdInputError(f'{name} needs at least 3 vertices as x1, y1, x2, y2, ... '
                             f'(an even count ≥ 6), got {flat.size} numbers')
    return flat.reshape(-1, 2)


def circles_from_flat(values, name: str = 'obstacles') -> np.ndarray:
    """[x, y, r, ...] -> (M, 3); empty -> (0, 3)."""
    flat = np.asarray(list(values), dtype=float).ravel()
    if flat.size % 3:
        raise HerdInputError(f'{name} needs triples x, y, r; got {flat.size} numbers')
    circles = flat.reshape(-1, 3)
    if not np.isfinite(circles).all() or (circles[:, 2] <= 0).any():
        raise HerdInputError(f'{name}: every radius must be positive and every number finite')
    return circles


class Fence:
    """A simple polygon (M, 2) vertices (either orientation, closed implicitly) in metres."""

    def __init__(self, vertices: np.ndarray):
        v = np.asarray(vertices, dtype=float).reshape(-1, 2)
        if len(v) >= 2 and np.allclose(v[0], v[-1]):
            v = v[:-1]
        if len(v) < 3 or not np.isfinite(v).all():
            raise HerdInputError('fence needs at least 3 finite vertices')
        area = 0.5 * _cross(v, np.roll(v, -1, axis=0)).sum()
        if abs(area) < 1e-9:
            raise HerdInputError('fence polygon has zero area')
        self.vertices = v
        self.start = v
        self.end = np.roll(v, -1, axis=0)
        self.edge = self.end - self.start
        length = _norm(self.edge)
        tangent = self.edge / length[:, None]
        # outward normal: right of the edge for a counter-clockwise polygon, left for clockwise
        sign = 1.0 if area > 0 else -1.0
        self.outward = sign * np.stack([tangent[:, 1], -tangent[:, 0]], axis=-1)
        self.tangent = tangent
        self._path = Path(np.vstack([v, v[:1]]), closed=True)

    @staticmethod
    def from_flat(values, name: str = 'fence') -> 'Fence | None':
        """The fence of a flat [x1, y1, x2, y2, ...] list (None when empty); one clear error
        naming ``name`` otherwise."""
        vertices = polygon_from_flat(values, name)
        return None if vertices is None else Fence(vertices)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Point in polygon (matplotlib.path.Path) for (N, 2) -> (N,) bool."""
        return self._path.contains_points(np.asarray(points, dtype=float).reshape(-1, 2))

    def nearest_boundary_point(self, points: np.ndarray):
        """Nearest boundary point (N, 2) and distance (N,) of each of (N, 2) points."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        rel = p[:, None, :] - self.start[None]                       # (N, M, 2)
        along = (rel * self.edge).sum(-1) / (self.edge ** 2).sum(-1)
        foot = self.start + np.clip(along, 0.0, 1.0)[..., None] * self.edge
        dist = _norm(p[:, None, :] - foot)
        k = dist.argmin(axis=1)
        rows = np.arange(len(p))
        return foot[rows, k], dist[rows, k]

    def first_crossing(self, start: np.ndarray, end: np.ndarray):
        """First crossing of segments start → end (N, 2) with the fence.

        Returns (t (N,), edge (N,)): the smallest fraction t ∈ [0, 1] along the segment where
        it meets an edge (inf where it meets none) and that edge's index (−1 if none).
        """
        p = np.asarray(start, dtype=float).reshape(-1, 2)
        r = np.asarray(end, dtype=float).reshape(-1, 2) - p
        s = self.edge[None]                                           # (1, M, 2)
        qp = self.start[None] - p[:, None, :]                         # (N, M, 2)
        denom = _cross(r[:, None, :], s)                              # (N, M)
        with np.errstate(divide='ignore', invalid='ignore'):
            t = _cross(qp, s) / denom
            u = _cross(qp, r[:, None, :]) / denom
        hit = (denom != 0) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
        t = np.where(hit, t, np.inf)
        edge = t.argmin(axis=1)
        t_first = t[np.arange(len(p)), edge]
        return t_first, np.where(np.isfinite(t_first), edge, -1)

    def scale_to_stay_inside(self, positions, velocity, horizon: float, margin: float = 0.0):
        """Shorten each v (direction kept) so p → p + h v stops ``margin`` short of the fence.

        Returns the scaled velocities (N, 2) and a bool mask of robots that were slowed.
        """
        p = np.asarray(positions, dtype=float).reshape(-1, 2)
        v = np.asarray(velocity, dtype=float).reshape(-1, 2)
        length = horizon * _norm(v)
        moving = length > 0
        with np.errstate(divide='ignore', invalid='ignore'):
            unit = np.where(moving[:, None], v / np.where(moving, _norm(v), 1.0)[:, None], 0.0)
        reach = p + (length + margin)[:, None] * unit
        t, _ = self.first_crossing(p, reach)
        allowed = np.maximum(t * (length + margin) - margin, 0.0)
        with np.errstate(divide='ignore', invalid='ignore'):
            scale = np.where(moving & np.isfinite(t), np.minimum(allowed / length, 1.0), 1.0)
        return v * scale[:, None], scale < 1.0

    def slide_along(self, positions, velocity, horizon: float, margin: float = 0.0):
        """Remove the outward-normal part of v at the edge its path would cross first.

        The robot may still approach that edge's line up to ``margin``: v·n ≤ (d − m)/h with
        d its distance to the line; the tangential part is kept so it slides along the fence.
        """
        p = np.asarray(positions, dtype=float).reshape(-1, 2)
        v = np.asarray(velocity, dtype=float).reshape(-1, 2).copy()
        speed = _norm(v)
        with np.errstate(divide='ignore', invalid='ignore'):
            unit = np.where(speed[:, None] > 0, v / speed[:, None], 0.0)
        reach = p + (horizon * speed + margin)[:, None] * unit
        _, edge = self.first_crossing(p, reach)
        hit = edge >= 0
        if hit.any():
            n = self.outward[edge[hit]]
            normal_speed = (v[hit] * n).sum(-1)
            dist = -((p[hit] - self.start[edge[hit]]) * n).sum(-1)      # inside: positive
            allowed = np.maximum(dist - margin, 0.0) / horizon
            excess = np.maximum(normal_speed - allowed, 0.0)
            v[hit] -= excess[:, None] * n
        return v

    def safe_velocity(self, positions, velocity, horizon: float, margin: float = 0.0):
        """Slide, then shorten (inside robots); toward-the-fence only (outside robots).

        Returns (velocity (N, 2), changed (N,) bool).
        """
        p = np.asarray(positions, dtype=float).reshape(-1, 2)
        v0 = np.asarray(velocity, dtype=float).reshape(-1, 2)
        v = self.slide_along(p, v0, horizon, margin)
        v, _ = self.scale_to_stay_inside(p, v, horizon, margin)
        outside = ~self.contains(p)
        if outside.any():
            foot, dist = self.nearest_boundary_point(p[outside])
            toward = (foot - p[outside]) / np.maximum(dist, 1e-12)[:, None]
            v[outside] = np.maximum((v0[outside] * toward).sum(-1), 0.0)[:, None] * toward
        changed = ~np.isclose(v, v0, rtol=0, atol=1e-12).all(-1)
        return v, changed


class Obstacles:
    """Circular obstacles (M, 3) rows [x, y, r] in metres."""

    def __init__(self, circles: np.ndarray):
        self.circles = np.asarray(circles, dtype=float).reshape(-1, 3)
        self.centers = self.circles[:, :2]
        self.radii = self.circles[:, 2]

    @staticmethod
    def from_flat(values, name: str = 'obstacles') -> 'Obstacles':
        """The obstacles of a flat [x, y, r, ...] list; one clear error naming ``name``
        otherwise."""
        return Obstacles(circles_from_flat(values, name))

    def __len__(self):
        return len(self.circles)

    def overlapping(self, positions: np.ndarray, robot_radius: float = 0.0) -> np.ndarray:
        """(N, M) bool: robot disc of ``robot_radius`` overlaps obstacle m."""
        p = np.asarray(positions, dtype=float).reshape(-1, 2)
        d = _norm(p[:, None, :] - self.centers[None])
        return d < self.radii[None] + robot_radius

    def collisions(self, positions: np.ndarray, robot_radius: float = 0.0) -> np.ndarray:
        """(N,) number of obstacles each robot currently overlaps."""
        return self.overlapping(positions, robot_radius).sum(axis=1)

    def safe_velocity(self, positions, velocity, horizon: float, margin: float = 0.0):
        """Keep paths p → p + h v out of the discs r + margin (slide, then shorten).

        A robot already inside an inflated disc may only move outward or tangentially.
        Returns (velocity (N, 2), changed (N,) bool).
        """
        v0 = np.asarray(velocity, dtype=float).reshape(-1, 2)
        v = self.shorten(positions, self.slide(positions, v0, horizon, margin), horizon, margin)
        changed = ~np.isclose(v, v0, rtol=0, atol=1e-12).all(-1)
        return v, changed

    def _geometry(self, positions, margin):
        p = np.asarray(positions, dtype=float).reshape(-1, 2)
        rel = self.centers[None] - p[:, None, :]                      # p -> centre, (N, M, 2)
        dist = _norm(rel)
        return p, rel, dist, self.radii + margin

    def slide(self, positions, velocity, horizon: float, margin: float = 0.0):
        """Cap the inward radial speed for every disc the path p → p + h v would enter.

        Inward speed v·r̂ ≤ max(d − (r + m), 0)/h with d the distance to the centre: the robot
        may close in up to the inflated disc; the tangential part is kept, so it slides round.
        """
        v = np.asarray(velocity, dtype=float).reshape(-1, 2).copy()
        if len(self) == 0:
            return v
        p, rel, dist, radius = self._geometry(positions, margin)
        radial = rel / np.maximum(dist, 1e-12)[..., None]
        for m in range(len(self)):          # obstacles are few; robots stay vectorised
            d = horizon * v
            dd = np.maximum((d ** 2).sum(-1), 1e-300)
            t = np.clip((rel[:, m] * d).sum(-1) / dd, 0.0, 1.0)
            closest = _norm(p + t[:, None] * d - self.centers[m])
            inward = (v * radial[:, m]).sum(-1)
            allowed = np.maximum(dist[:, m] - radius[m], 0.0) / horizon
            excess = np.where(closest < radius[m], np.maximum(inward - allowed, 0.0), 0.0)
            v -= excess[:, None] * radial[:, m]
        return v

    def shorten(self, positions, velocity, horizon: float, margin: float = 0.0):
        """Scale v so p → p + h v stops where it would first enter a disc it is outside of.

        Solves ‖p + t h v − c‖ = r + m for the smaller root t ∈ [0, 1] (ray–circle).
        """
        v = np.asarray(velocity, dtype=float).reshape(-1, 2).copy()
        if len(self) == 0:
            return v
        p, rel, dist, radius = self._geometry(positions, margin)
        d = horizon * v                                               # (N, 2)
        a = (d ** 2).sum(-1)[:, None]                                 # |d|²
        b = -2.0 * (rel * d[:, None, :]).sum(-1)                      # 2 d·(p − c)
        c = dist ** 2 - radius[None] ** 2
        disc = b ** 2 - 4 * a * c
        with np.errstate(divide='ignore', invalid='ignore'):
            t_enter = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2 * a)
        enters = (c > 0) & (a > 0) & (disc > 0) & (t_enter >= 0) & (t_enter <= 1)
        return v * np.where(enters, t_enter, 1.0).min(axis=1)[:, None]


def safe_velocity(positions, velocity, horizon: float, max_speed: float,
                  fence: Fence | None = None, obstacles: Obstacles | None = None,
                  margin: float = 0.0):
    """The whole layer: speed limit, obstacles, fence, then obstacles shortened once more.

    Each "slide" may turn a velocity, each "shorten" only scales it; the last step is a
    shortening, and shortening a path that already satisfies a constraint keeps it
    satisfied (a sub-segment), so the result respects the speed limit, the fence and the
    obstacles together (for a robot that starts inside the fence and outside the discs).

    Returns (velocity (N, 2), report) with ``report`` a dict of bool masks (N,):
    ``speed_limited``, ``obstacle_limited``, ``fence_limited``.
    """
    v0 = np.asarray(velocity, dtype=float).reshape(-1, 2)
    v = limit_speed(v0, max_speed)
    report = {'speed_limited': _norm(v0) > max_speed}
    n = len(v)
    report['obstacle_limited'] = np.zeros(n, bool)
    report['fence_limited'] = np.zeros(n, bool)
    has_obstacles = obstacles is not None and len(obstacles) > 0
    if has_obstacles:
        v, report['obstacle_limited'] = obstacles.safe_velocity(positions, v, horizon, margin)
    if fence is not None:
        v, report['fence_limited'] = fence.safe_velocity(positions, v, horizon, margin)
    if has_obstacles and fence is not None:
        # the fence may have turned a path; shortening keeps it a sub-segment, so both hold
        v = obstacles.shorten(positions, v, horizon, margin)
    return v, report
