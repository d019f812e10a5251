"""Per-step flocking metrics (Olfati-Saber 2006 §II and §VIII; La & Sheng 2009).

For agents q_i (N, 2), velocities p_i, the r-disc graph E(q) = {(i, j): ‖q_j − q_i‖ < r}
and the target q_r:

* deviation energy (how far the conformation is from an α-lattice of spacing d),
  ``E(q) = 1/(|E| + 1) Σ_i Σ_{j∈N_i} (‖q_j − q_i‖ − d)²``, |E| counting ordered pairs
  (Olfati-Saber 2006, "deviation energy"), m²;
* velocity mismatch, ``K = (1/n) Σ_i ‖p_i − p̄‖²`` (Olfati-Saber's kinetic energy in the
  moving frame ``½ Σ ‖p_i − p̄‖²`` divided by n/2 so flocks of any size compare), m²/s²;
* cohesion radius ``R = max_i ‖q_i − q̄‖``, m;
* relative connectivity ``C = rank(L(q))/(n − 1)``, L the Laplacian of the r-disc graph;
  ``rank(L) = n − #connected components`` (exact), so C = 1 iff the graph is connected;
* CoM-to-target squared error ``‖q̄ − q_r‖²`` (La & Sheng 2009 tracking error), m²;
* collisions: the number of agents strictly inside an obstacle circle.

Each can be computed over a subset (``members``, e.g. the non-adversarial agents): the
graph is then the r-disc graph among the members only.
"""
from __future__ import annotations

import numpy as np

from herd_ros.flocking.olfati_saber import CircularObstacles, neighbour_pairs

METRIC_NAMES = ('deviation_energy', 'velocity_mismatch', 'cohesion_radius', 'connectivity',
                'tracking_mse', 'collisions')


def deviation_energy(positions, pairs, distance: float) -> float:
    """E(q) = 1/(|E| + 1) Σ_{ordered (i,j)∈E} (‖q_j − q_i‖ − d)², with ``pairs`` the (P, 2)
    unordered edges (each counted twice, as in the double sum)."""
    if len(pairs) == 0:
        return 0.0
    q = np.asarray(positions, dtype=float)
    lengths = np.linalg.norm(q[pairs[:, 1]] - q[pairs[:, 0]], axis=1)
    return float(2.0 * np.sum((lengths - distance) ** 2) / (2 * len(pairs) + 1))


def velocity_mismatch(velocities) -> float:
    """K = (1/n) Σ ‖p_i − p̄‖² (m²/s²)."""
    p = np.asarray(velocities, dtype=float)
    return float(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1)))


def cohesion_radius(positions) -> float:
    """R = max_i ‖q_i − q̄‖ (m)."""
    q = np.asarray(positions, dtype=float)
    return float(np.max(np.linalg.norm(q - q.mean(axis=0), axis=1)))


def relative_connectivity(n: int, pairs) -> float:
    """C = rank(L)/(n − 1) = (n − #components)/(n − 1) for the graph with edges ``pairs``."""
    from scipy.sparse import coo_matrix     # here: `herd-ros flock --help` imports no scipy
    from scipy.sparse.csgraph import connected_components
    if n < 2:
        return 1.0
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    n_components = connected_components(graph, directed=False, return_labels=False)
    return float((n - n_components) / (n - 1))


def tracking_squared_error(positions, target_position) -> float:
    """‖q̄ − q_r‖² (m²): squared distance of the centre of mass to the target."""
    q = np.asarray(positions, dtype=float)
    return float(np.sum((q.mean(axis=0) - np.asarray(target_position, dtype=float)) ** 2))


def count_collisions(positions, obstacles: CircularObstacles | None) -> int:
    """Number of agents strictly inside at least one obstacle circle (obstacles at the
    current time)."""
    if obstacles is None or len(obstacles) == 0:
        return 0
    q = np.asarray(positions, dtype=float)
    d = np.linalg.norm(q[:, None, :] - obstacles.centres[None, :, :], axis=2)
    return int(np.count_nonzero(np.any(d < obstacles.radii[None, :], axis=1)))


def subgraph_pairs(pairs, members) -> tuple[np.ndarray, np.ndarray]:
    """Edges among ``members`` (bool (N,) mask), re-indexed to 0..m−1; also the index map."""
    members = np.asarray(members, dtype=bool)
    index = np.cumsum(members) - 1
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    keep = members[pairs[:, 0]] & members[pairs[:, 1]]
    return index[pairs[keep]], np.flatnonzero(members)


def step_metrics(positions, velocities, target_position, distance: float, radius: float,
                 obstacles: CircularObstacles | None = None, pairs=None,
                 members=None) -> dict[str, float]:
    """All metrics of one step (names in :data:`METRIC_NAMES`).

    Args:
        positions, velocities: (N, 2) all agents.
        target_position: (2,) q_r.
        distance: lattice spacing d (m); radius: interaction range r (m).
        obstacles: obstacles at this time, or None.
        pairs: r-disc edges of all agents if already computed (see ``neighbour_pairs``).
        members: optional bool (N,) mask; the metrics then cover these agents only.
    """
    q = np.asarray(positions, dtype=float)
    p = np.asarray(velocities, dtype=float)
    if pairs is None:
        pairs = neighbour_pairs(q, radius)
    if members is not None:
        pairs, idx = subgraph_pairs(pairs, members)
        q, p = q[idx], p[idx]
    return {
        'deviation_energy': deviation_energy(q, pairs, distance),
        'velocity_mismatch': velocity_mismatch(p),
        'cohesion_radius': cohesion_radius(q),
        'connectivity': relative_connectivity(len(q), pairs),
        'tracking_mse': tracking_squared_error(q, target_position),
        'collisions': count_collisions(q, obstacles),
    }
