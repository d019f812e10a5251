"""Policy features θ_k,i of Rahman, White et al., "Imitation of swarm behaviours" (ACC 2023).

Each agent i commands ``v_i = σ_vmax(Σ_k k_k θ_k,i)`` (see :mod:`herd_ros.imitation.boids`);
this module computes the features ``θ_k,i`` (2-vectors, one per policy k) for every agent of
many frames at once. Neighbours of i are the agents j ≠ i with ‖p_j − p_i‖ < r (strict).

Policies (``N_i`` = neighbour set, ``n_i = |N_i|``, ``p`` positions (m), ``v`` the agents'
*previous* velocities (m/s, the velocity each agent showed on the last step), ``h_i`` the unit
heading ``v_i/‖v_i‖``; an agent without neighbours gets a zero vector from every neighbour
policy — it simply does not react — and an agent with ``v_i = 0`` has no heading, so its
heading-based policies (steer-to-avoid, wall steer) are zero):

``cohesion``        C_i = (1/n_i) Σ_{j∈N_i} p_j − p_i                      (m)
``separation<e>``   S_i = Σ_{j∈N_i} (p_i − p_j)/‖p_i − p_j‖^{e+1}           (magnitude Σ 1/d^e);
                    coincident pairs (d = 0) have no direction and contribute nothing.
``alignment``       A_i = (1/n_i) Σ_{j∈N_i} v_j                             (m/s)
``rotation``        R_i = C_i rotated by +90°: (−C_y, C_x)
``steer_to_avoid``  the paper only says "steer away from the agent ahead". Here: j* is the
                    nearest neighbour *ahead* (h_i · (p_j − p_i) > 0); with d = p_j* − p_i and
                    its lateral part l = d − (d·h_i) h_i, SA_i = −(l/‖l‖) / ‖d‖: a push sideways,
                    away from j*, growing as 1/distance. If j* is dead ahead (l = 0) the push is
                    to the left, h_i rotated +90°. Zero if no neighbour is ahead.
``wall_separation`` walls are an axis-aligned rectangle (xmin, xmax, ymin, ymax); wall w has
                    inward normal n_w and distance d_w = signed distance of p_i to it (positive
                    inside). WSep_i = Σ_{w: d_w < r} n_w / max(d_w, d_min)², d_min = 0.05 m, so an
                    agent that left the enclosure is pushed back with the largest force.
``wall_steer``      for each wall within r that the agent is heading into (h_i·n_w < 0):
                    t_w = n_w rotated +90°, flipped to the side of the heading (h_i·t_w ≥ 0);
                    WSt_i = Σ_w t_w / max(d_w, d_min): turn to run along the wall.
``inertia``         I_i = v_i (own previous velocity).

Without walls the wall policies are zero. Vectorised with numpy; neighbour pairs come from a
dense distance matrix for small swarms and :class:`scipy.spatial.cKDTree` for large ones.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from herd_ros.errors import HerdInputError

BASE_POLICIES = ('cohesion', 'alignment', 'rotation', 'steer_to_avoid', 'wall_separation',
                 'wall_steer', 'inertia')
ALL_POLICIES = ('cohesion', 'separation2', 'alignment', 'rotation', 'steer_to_avoid',
                'wall_separation', 'wall_steer', 'inertia')
WALL_MIN_DISTANCE = 0.05  # m, d_min of the wall policies
DENSE_MAX_AGENTS = 200     # above this many agents per frame, neighbour pairs come from cKDTree
_SEPARATION = re.compile(r'^separation(\d+(?:\.\d+)?)$')


def separation_exponent(name: str) -> float | None:
    """The exponent e of a ``separation<e>`` policy name, or ``None`` for other names."""
    m = _SEPARATION.match(name)
    return float(m.group(1)) if m else None


def check_policies(policies, where: str = 'policies') -> list[str]:
    """Validated list of policy names; raises :class:`HerdInputError` on an unknown one."""
    names = [str(p).strip() for p in policies]
    if not names:
        raise HerdInputError(f'{where}: no policy given')
    for p in names:
        if p not in BASE_POLICIES and separation_exponent(p) is None:
            raise HerdInputError(
                f'{where}: unknown policy {p!r}; known: {", ".join(BASE_POLICIES)} and '
                f'separation<e> (e.g. separation2)')
    if len(set(names)) != len(names):
        raise HerdInputError(f'{where}: policy names repeat ({", ".join(names)})')
    return names


def check_walls(walls, where: str = 'walls') -> np.ndarray | None:
    """Walls as an array (xmin, xmax, ymin, ymax) or ``None``."""
    if walls is None or len(walls) == 0:
        return None
    w = np.asarray(walls, dtype=float)
    if w.shape != (4,) or not np.isfinite(w).all() or w[0] >= w[1] or w[2] >= w[3]:
        raise HerdInputError(f'{where}: need four finite numbers xmin < xmax, ymin < ymax '
                             f'(got {list(walls)})')
    return w


def rotate90(vectors: np.ndarray) -> np.ndarray:
    """Rotate 2-vectors (..., 2) by +90°: (x, y) -> (−y, x)."""
    return np.stack([-vectors[..., 1], vectors[..., 0]], axis=-1)


@dataclass
class NeighbourPairs:
    """Ordered pairs (i, j), i ≠ j, with ‖p_i − p_j‖ < ``max_radius``, sorted by distance.

    Indices are *flat sample* indices into the (S, 2) arrays of :func:`pair_geometry`, so pairs
    of different frames never mix. ``diff = p_i − p_j`` (m), ``dist`` its norm. Because the
    pairs are sorted by distance, the neighbours within any r ≤ max_radius are a prefix.
    """

    i: np.ndarray
    j: np.ndarray
    dist: np.ndarray
    diff: np.ndarray
    n_samples: int
    max_radius: float

    def within(self, radius: float) -> slice:
        """The prefix of pairs with distance < ``radius``."""
        if radius > self.max_radius + 1e-12:
            raise ValueError(f'radius {radius} exceeds the pairs\' max_radius {self.max_radius}')
        return slice(0, int(np.searchsorted(self.dist, radius, side='left')))


def pair_geometry(positions: np.ndarray, frame_sizes, max_radius: float) -> NeighbourPairs:
    """Neighbour pairs of every frame, for flat positions.

    Args:
        positions: (S, 2) metres, the agents of frame 0, then frame 1, ... (flat samples).
        frame_sizes: (F,) number of agents in each frame (sums to S).
        max_radius: largest radius the pairs will be queried with (m).
    """
    positions = np.asarray(positions, dtype=float)
    sizes = np.asarray(frame_sizes, dtype=int)
    S = positions.shape[0]
    if sizes.sum() != S:
        raise ValueError('frame_sizes must sum to the number of samples')
    ii, jj = [], []
    uniq = np.unique(sizes)
    r2 = max_radius ** 2
    if len(uniq) == 1 and uniq[0] <= DENSE_MAX_AGENTS:
        n = int(uniq[0])
        P = positions.reshape(-1, n, 2)
        dx = P[:, :, None, 0] - P[:, None, :, 0]
        dy = P[:, :, None, 1] - P[:, None, :, 1]
        d2 = dx * dx + dy * dy
        d2[:, np.arange(n), np.arange(n)] = np.inf
        f, a, b = np.nonzero(d2 < r2)
        ii.append(f * n + a)
        jj.append(f * n + b)
    else:
        from scipy.spatial import cKDTree
        start = 0
        for n in sizes:  # one tree per frame: a loop over frames, not agents
            if n > 1:
                P = positions[start:start + n]
                pairs = cKDTree(P).query_pairs(max_radius, output_type='ndarray')
                if len(pairs):
                    dd = P[pairs[:, 0]] - P[pairs[:, 1]]
                    pairs = pairs[np.einsum('pd,pd->p', dd, dd) < r2]
                    ii += [start + pairs[:, 0], start + pairs[:, 1]]
                    jj += [start + pairs[:, 1], start + pairs[:, 0]]
            start += n
    i = np.concatenate(ii) if ii else np.zeros(0, int)
    j = np.concatenate(jj) if jj else np.zeros(0, int)
    diff = positions[i] - positions[j]
    dist = np.sqrt(np.einsum('pd,pd->p', diff, diff))
    order = np.argsort(dist)
    return NeighbourPairs(i[order], j[order], dist[order], diff[order], S, float(max_radius))


def _sum_over_pairs(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Σ of (P, 2) pair values per receiving sample: (n, 2)."""
    return np.stack([np.bincount(index, values[:, 0], minlength=n),
                     np.bincount(index, values[:, 1], minlength=n)], axis=1)


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = np.linalg.norm(v, axis=-1)
    safe = np.where(norm > 0, norm, 1.0)
    return v / safe[..., None], norm > 0


def _wall_geometry(positions, walls):
    """Inward normals (4, 2) and signed distances (S, 4) to the walls xmin, xmax, ymin, ymax."""
    normals = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    x, y = positions[:, 0], positions[:, 1]
    d = np.stack([x - walls[0], walls[1] - x, y - walls[2], walls[3] - y], axis=1)
    return normals, d


class RadiusFeatures:
    """Policy features of flat samples at any radius r ≤ ``pairs.max_radius``, cheaply.

    The neighbour policies are sums over pairs (count, Σ(p_i − p_j), Σ(p_i − p_j)/d^{e+1},
    Σ v_j), additive in the pairs; pairs are sorted by distance, so the sums at r are the sums
    at the largest already-evaluated r' < r plus the pairs with r' ≤ d < r. A radius search
    therefore touches every pair about once. Steer-to-avoid uses the nearest neighbour ahead,
    found once over all pairs: it is the one within r if its distance is < r.

    Args:
        pairs: from :func:`pair_geometry` on ``positions``.
        positions: (S, 2) m. velocities: (S, 2) m/s, each agent's previous velocity.
        policies: names (module docstring). walls: (xmin, xmax, ymin, ymax) or None.
    """

    def __init__(self, pairs: NeighbourPairs, positions, velocities, policies, walls=None):
        self.pairs = pairs
        self.positions = np.asarray(positions, dtype=float)
        self.velocities = np.asarray(velocities, dtype=float)
        self.policies = list(policies)
        self.walls = check_walls(walls)
        self.exponents = sorted({e for e in map(separation_exponent, self.policies)
                                 if e is not None})
        self._cache = {0: self._empty()}       # pair-prefix length -> sums
        self.heading, self.moving = _unit(self.velocities)
        if 'steer_to_avoid' in self.policies:
            self._nearest_ahead()

    def _empty(self):
        S = self.pairs.n_samples
        sums = {'count': np.zeros(S), 'diff': np.zeros((S, 2)), 'vel': np.zeros((S, 2))}
        for e in self.exponents:
            sums[e] = np.zeros((S, 2))
        return sums

    def _nearest_ahead(self):
        p = self.pairs
        to_j = -p.diff                                       # p_j − p_i
        ahead = np.einsum('pd,pd->p', self.heading[p.i], to_j) > 0
        ahead &= self.moving[p.i] & (p.dist > 0)
        ai = p.i[ahead]
        first = np.unique(ai, return_index=True)[1]          # sorted by distance: nearest
        self._sa_index = ai[first]
        self._sa_dist = p.dist[ahead][first]
        d = to_j[ahead][first]
        h = self.heading[self._sa_index]
        lateral = d - np.einsum('pd,pd->p', d, h)[:, None] * h
        lat_unit, has_lat = _unit(lateral)
        away = np.where(has_lat[:, None], -lat_unit, rotate90(h))
        self._sa_value = away / self._sa_dist[:, None]

    def _sums(self, radius):
        p = self.pairs
        stop = p.within(radius).stop
        if stop in self._cache:
            return self._cache[stop]
        start = max(k for k in self._cache if k <= stop)
        base = self._cache[start]
        sl = slice(start, stop)
        pi, dist, diff = p.i[sl], p.dist[sl], p.diff[sl]
        S = p.n_samples
        sums = {'count': base['count'] + np.bincount(pi, minlength=S),
                'diff': base['diff'] + _sum_over_pairs(pi, diff, S),
                'vel': base['vel'] + _sum_over_pairs(pi, self.velocities[p.j[sl]], S)}
        ok = dist > 0
        for e in self.exponents:
            w = np.zeros_like(dist)
            w[ok] = dist[ok] ** -(e + 1.0)
            sums[e] = base[e] + _sum_over_pairs(pi, diff * w[:, None], S)
        self._cache[stop] = sums
        return sums

    def at(self, radius: float) -> np.ndarray:
        """(S, K, 2) features θ_k,i at communication radius ``radius`` (m)."""
        sums = self._sums(radius)
        S = self.pairs.n_samples
        count = sums['count']
        inv_count = np.where(count > 0, 1.0 / np.maximum(count, 1.0), 0.0)[:, None]
        out = np.zeros((S, len(self.policies), 2))
        for k, name in enumerate(self.policies):
            e = separation_exponent(name)
            if name == 'cohesion':
                out[:, k] = -sums['diff'] * inv_count
            elif e is not None:
                out[:, k] = sums[e]
            elif name == 'alignment':
                out[:, k] = sums['vel'] * inv_count
            elif name == 'rotation':
                out[:, k] = rotate90(-sums['diff'] * inv_count)
            elif name == 'steer_to_avoid':
                inside = self._sa_dist < radius
                out[self._sa_index[inside], k] = self._sa_value[inside]
            elif name in ('wall_separation', 'wall_steer'):
                if self.walls is None:
                    continue
                normals, d = _wall_geometry(self.positions, self.walls)
                near = d < radius
                dc = np.maximum(d, WALL_MIN_DISTANCE)
                if name == 'wall_separation':
                    out[:, k] = np.einsum('sw,wd->sd', near / dc ** 2, normals)
                else:
                    tang = rotate90(normals)                  # (4, 2)
                    into = (self.heading @ normals.T) < 0     # (S, 4)
                    side = np.where(self.heading @ tang.T >= 0, 1.0, -1.0)
                    wgt = (near & into & self.moving[:, None]) * side / dc
                    out[:, k] = np.einsum('sw,wd->sd', wgt, tang)
            elif name == 'inertia':
                out[:, k] = self.velocities
            else:
                raise HerdInputError(f'unknown policy {name!r}')
        return out


def features_from_pairs(pairs: NeighbourPairs, positions: np.ndarray, velocities: np.ndarray,
                        policies, radius: float, walls=None) -> np.ndarray:
    """Policy features for flat samples, given their precomputed neighbour pairs.

    Args:
        pairs: from :func:`pair_geometry` on the same ``positions``.
        positions: (S, 2) m. velocities: (S, 2) m/s, each agent's previous velocity.
        policies: names (see module docstring). radius: r (m). walls: (xmin, xmax, ymin, ymax).

    Returns:
        (S, K, 2) features θ_k,i in the order of ``policies``.
    """
    return RadiusFeatures(pairs, positions, velocities, policies, walls).at(radius)


def policy_features(positions: np.ndarray, velocities: np.ndarray, policies, radius: float,
                    walls=None) -> np.ndarray:
    """Policy features of every agent of one or many frames.

    Args:
        positions: (..., N, 2) metres; leading axes are independent frames (times, runs).
        velocities: (..., N, 2) m/s, each agent's previous velocity.
        policies: policy names, e.g. ``['cohesion', 'separation2', 'alignment']``.
        radius: communication radius r (m); neighbours are j ≠ i with ‖p_j − p_i‖ < r.
        walls: optional rectangle (xmin, xmax, ymin, ymax), metres.

    Returns:
        (..., N, K, 2) features θ_k,i.
    """
    positions = np.asarray(positions, dtype=float)
    velocities = np.asarray(velocities, dtype=float)
    policies = check_policies(policies)
    lead, n = positions.shape[:-2], positions.shape[-2]
    P = positions.reshape(-1, 2)
    V = np.broadcast_to(velocities, positions.shape).reshape(-1, 2)
    frames = max(1, int(np.prod(lead)))
    pairs = pair_geometry(P, np.full(frames, n), radius)
    out = features_from_pairs(pairs, P, V, policies, radius, walls)
    return out.reshape(*lead, n, len(policies), 2)
