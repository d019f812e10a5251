"""Olfati-Saber (2006) flocking with La & Sheng (2009) centre-of-mass target feedback.

Agents are double integrators in the plane, ``q_i' = p_i``, ``p_i' = u_i`` (positions ``q``
in metres, velocities ``p`` in m/s, accelerations ``u`` in m/s²). The control is the sum of
three terms (Olfati-Saber 2006, Algorithm 3; La & Sheng 2009; the report
"Decentralized Flocking Control for Dynamic Object Tracking")::

    u_i = u_i^α + u_i^β + u_i^γ

    u_i^α = c1α Σ_{j∈N_i} φ_α(‖q_j − q_i‖_σ) n_ij + c2α Σ_{j∈N_i} a_ij(q) (p_j − p_i)
    u_i^β = c1β Σ_{k∈N_i^β} φ_β(‖q̂_ik − q_i‖_σ) n̂_ik + c2β Σ_k b_ik(q) (p̂_ik − p_i)
    u_i^γ = −c1γ (q_i − q_r) − c2γ (p_i − p_r)                                  (plain)
            − c1mc (q̄ − q_r) − c2mc (p̄ − p_r)      q̄, p̄ over the flock     (global-com, eq. 5)
            − c1mc (q̄_i − q_r) − c2mc (p̄_i − p_r)  over N_i ∪ {i}          (local-com, eq. 6)

with N_i = {j : ‖q_j − q_i‖ < r} (the r-disc graph) and

* σ-norm ``‖z‖_σ = (√(1 + ε‖z‖²) − 1)/ε`` (differentiable everywhere, §II);
* its gradient ``n_ij = σ_ε(q_j − q_i) = (q_j − q_i)/√(1 + ε‖q_j − q_i‖²)``;
* bump ``ρ_h(z) = 1`` on [0, h), ``½[1 + cos(π (z − h)/(1 − h))]`` on [h, 1], 0 beyond (§II);
* ``a_ij(q) = ρ_hα(‖q_j − q_i‖_σ / r_α)`` with ``r_α = ‖r‖_σ``;
* ``φ(z) = ½[(a + b) σ1(z + c) + (a − b)]``, ``σ1(z) = z/√(1 + z²)``, ``c = |a − b|/√(4ab)``;
  ``φ_α(z) = ρ_hα(z / r_α) φ(z − d_α)`` with ``d_α = ‖d‖_σ`` (§II–III);
* β-agents (Olfati-Saber 2006 §VI, Lemma 4): on a circular obstacle with centre ``y_k`` and
  radius ``R_k``, ``μ = R_k/‖q_i − y_k‖``, ``a_k = (q_i − y_k)/‖q_i − y_k‖``,
  ``P = I − a_k a_kᵀ``, ``q̂_ik = μ q_i + (1 − μ) y_k``, ``p̂_ik = μ P p_i``. For an obstacle
  moving at ``v_k`` the projection is taken in the obstacle's frame:
  ``p̂_ik = μ P (p_i − v_k) + v_k`` (reduces to the paper's for ``v_k = 0``);
  ``φ_β(z) = ρ_hβ(z/d_β)(σ1(z − d_β) − 1)``, ``b_ik = ρ_hβ(‖q̂_ik − q_i‖_σ / d_β)``,
  ``d_β = ‖d'‖_σ``, ``r_β = ‖r'‖_σ``; only β-agents closer than ``r'`` act.

Constants (defaults of :class:`FlockingParams`, shipped in ``config/flocking.yaml``):

==============  ===========  ===================================================================
name            default      source
==============  ===========  ===================================================================
epsilon         0.1          σ-norm ε, Olfati-Saber 2006 §VIII
h_alpha         0.2          bump h of a_ij and φ_α, Olfati-Saber 2006 §VIII
h_beta          0.9          bump h of b_ik and φ_β, Olfati-Saber 2006 §VIII
a, b            5, 5         φ constants, Olfati-Saber 2006 §VIII (c = 0: φ odd, even pull/push)
range  (r)      9 m          interaction range, the report ("range 9")
distance (d)    7.5 m        lattice spacing. The paper uses d = 7, r = 1.2 d; the report fixes
                             r = 9 and gives no d, so we keep the paper's ratio: d = r/1.2
beta_distance   4.5 m        d' = 0.6 d, Olfati-Saber 2006 §VIII
beta_range      5.4 m        r' = 1.2 d', Olfati-Saber 2006 §VIII
c1_alpha        5            the report (c1α); c2_alpha = 2√c1α (the report, "c2 = 2√c1")
c1_beta         300          the report (c1β); c2_beta = 2√c1β
c1_gamma        15           the report (c1mt, target feedback); c2_gamma = 2√c1mt
c1_com          10           the report (c1mc, centre-of-mass feedback); c2_com = 2√c1mc
==============  ===========  ===================================================================

Why the gradient and consensus sums are written by hand: no library implements the
Olfati-Saber law; neighbour search is scipy's :class:`cKDTree` and the per-agent sums are
:func:`numpy.bincount` over the neighbour pairs, so one step costs O(N + pairs).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from herd_ros.errors import HerdInputError

GAMMA_MODES = ('plain', 'global-com', 'local-com')


def _two_sqrt(c1: float) -> float:
    return 2.0 * math.sqrt(c1)


@dataclass(frozen=True)
class FlockingParams:
    """Gains and constants of the flocking law (see the module docstring for sources).

    All gains are in 1/s² (c1) or 1/s (c2); distances in metres. ``c2_*`` left as ``None``
    become ``2√c1_*`` (the report's choice, critical damping of each feedback loop).
    """

    c1_alpha: float = 5.0
    c2_alpha: float | None = None
    c1_beta: float = 300.0
    c2_beta: float | None = None
    c1_gamma: float = 15.0
    c2_gamma: float | None = None
    c1_com: float = 10.0
    c2_com: float | None = None
    range: float = 9.0
    distance: float = 7.5
    beta_distance: float = 4.5
    beta_range: float = 5.4
    epsilon: float = 0.1
    h_alpha: float = 0.2
    h_beta: float = 0.9
    a: float = 5.0
    b: float = 5.0
    gamma_mode: str = 'local-com'

    def __post_init__(self):
        for name in ('c2_alpha', 'c2_beta', 'c2_gamma', 'c2_com'):
            if getattr(self, name) is None:
                c1 = getattr(self, 'c1' + name[2:])
                object.__setattr__(self, name, _two_sqrt(max(c1, 0.0)))
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == 'gamma_mode':
                continue
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise HerdInputError(f'flocking.{f.name} must be a finite number >= 0 (got {v!r})')
        if self.gamma_mode not in GAMMA_MODES:
            raise HerdInputError(f'flocking.gamma_mode must be one of {", ".join(GAMMA_MODES)} '
                                 f'(got {self.gamma_mode!r})')
        for name in ('range', 'distance', 'epsilon', 'a', 'b', 'beta_distance', 'beta_range'):
            if getattr(self, name) <= 0:
                raise HerdInputError(f'flocking.{name} must be > 0 (got {getattr(self, name)!r})')
        for name in ('h_alpha', 'h_beta'):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise HerdInputError(f'flocking.{name} must be in [0, 1) '
                                     f'(got {getattr(self, name)!r})')
        if self.distance >= self.range:
            raise HerdInputError(f'flocking.distance ({self.distance}) must be smaller than '
                                 f'flocking.range ({self.range})')

    @classmethod
    def from_mapping(cls, values: dict, where: str = 'flocking') -> 'FlockingParams':
        """Build from a ``flocking:`` parameter mapping (``config/flocking.yaml``); the key
        ``obstacles`` is ignored here (see :meth:`CircularObstacles.from_flat`)."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known - {'obstacles'})
        if unknown:
            raise HerdInputError(f'{where}: unknown parameter(s) {", ".join(unknown)}; '
                                 f'known: {", ".join(sorted(known | {"obstacles"}))}')
        kwargs = {}
        for k, v in values.items():
            if k == 'obstacles':
                continue
            if k == 'gamma_mode':
                kwargs[k] = str(v)
            else:
                try:
                    kwargs[k] = float(v)
                except (TypeError, ValueError):
                    raise HerdInputError(f'{where}.{k} must be a number (got {v!r})') from None
        return cls(**kwargs)

    def with_(self, **changes) -> 'FlockingParams':
        """A copy with some fields changed (c2 gains recomputed only if passed as None)."""
        return replace(self, **changes)

    @property
    def r_alpha(self) -> float:
        """r_α = ‖r‖_σ."""
        return float(sigma_norm_of_length(self.range, self.epsilon))

    @property
    def d_alpha(self) -> float:
        """d_α = ‖d‖_σ."""
        return float(sigma_norm_of_length(self.distance, self.epsilon))

    @property
    def d_beta(self) -> float:
        """d_β = ‖d'‖_σ."""
        return float(sigma_norm_of_length(self.beta_distance, self.epsilon))


@dataclass
class CircularObstacles:
    """K circular obstacles moving at constant velocity.

    Attributes:
        centres: (K, 2) m, centres at time 0.
        radii: (K,) m.
        velocities: (K, 2) m/s (zeros for static obstacles).
    """

    centres: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    radii: np.ndarray = field(default_factory=lambda: np.zeros(0))
    velocities: np.ndarray | None = None

    def __post_init__(self):
        self.centres = np.asarray(self.centres, dtype=float).reshape(-1, 2)
        self.radii = np.asarray(self.radii, dtype=float).reshape(-1)
        if self.velocities is None:
            self.velocities = np.zeros_like(self.centres)
        self.velocities = np.asarray(self.velocities, dtype=float).reshape(-1, 2)
        k = len(self.centres)
        if len(self.radii) != k or len(self.velocities) != k:
            raise HerdInputError(f'obstacles: {k} centres but {len(self.radii)} radii and '
                                 f'{len(self.velocities)} velocities')
        if np.any(~np.isfinite(self.centres)) or np.any(~np.isfinite(self.velocities)) \
                or np.any(~(self.radii > 0)):
            raise HerdInputError('obstacles: centres and velocities must be finite and radii > 0')

    def __len__(self):
        return len(self.radii)

    @classmethod
    def from_flat(cls, flat, where: str = 'flocking.obstacles') -> 'CircularObstacles':
        """From the ROS parameter form ``[x1, y1, r1, x2, y2, r2, ...]`` (static obstacles)."""
        flat = np.asarray(list(flat), dtype=float)
        if flat.size % 3:
            raise HerdInputError(f'{where} must hold triples x, y, r (got {flat.size} numbers)')
        flat = flat.reshape(-1, 3)
        return cls(flat[:, :2], flat[:, 2])

    def at_time(self, t: float) -> 'CircularObstacles':
        """The obstacles at time ``t`` (s): centres moved by ``velocities * t``."""
        return CircularObstacles(self.centres + self.velocities * t, self.radii, self.velocities)


# --- scalar functions of Olfati-Saber 2006 §II–III -----------------------------------------

def sigma_norm_of_length(length, epsilon: float):
    """σ-norm of a vector of Euclidean length ``length``: (√(1 + ε‖z‖²) − 1)/ε."""
    length = np.asarray(length, dtype=float)
    return (np.sqrt(1.0 + epsilon * length * length) - 1.0) / epsilon


def sigma_norm(z, epsilon: float):
    """σ-norm ‖z‖_σ of vectors z (..., 2) -> (...) (Olfati-Saber 2006 §II)."""
    z = np.asarray(z, dtype=float)
    return sigma_norm_of_length(np.linalg.norm(z, axis=-1), epsilon)


def sigma_gradient(z, epsilon: float):
    """σ_ε(z) = ∇‖z‖_σ = z/√(1 + ε‖z‖²), shape (..., 2)."""
    z = np.asarray(z, dtype=float)
    return z / np.sqrt(1.0 + epsilon * np.sum(z * z, axis=-1, keepdims=True))


def sigma_1(z):
    """σ1(z) = z/√(1 + z²) (uneven sigmoid of φ)."""
    z = np.asarray(z, dtype=float)
    return z / np.sqrt(1.0 + z * z)


def bump(z, h: float):
    """Bump function ρ_h(z) (Olfati-Saber 2006 §II): 1 on [0, h),
    ½[1 + cos(π(z − h)/(1 − h))] on [h, 1], 0 elsewhere (including z < 0)."""
    z = np.asarray(z, dtype=float)
    out = np.where((z >= 0) & (z < h), 1.0, 0.0)
    mid = (z >= h) & (z <= 1.0)
    return np.where(mid, 0.5 * (1.0 + np.cos(np.pi * (z - h) / (1.0 - h))), out)


def phi(z, a: float, b: float):
    """Uneven sigmoid φ(z) = ½[(a + b) σ1(z + c) + (a − b)], c = |a − b|/√(4ab)."""
    c = abs(a - b) / math.sqrt(4.0 * a * b)
    return 0.5 * ((a + b) * sigma_1(np.asarray(z, dtype=float) + c) + (a - b))


def phi_alpha(z, params: FlockingParams):
    """Action function φ_α(z) = ρ_hα(z/r_α) φ(z − d_α), z a σ-norm."""
    return bump(np.asarray(z) / params.r_alpha, params.h_alpha) * phi(
        np.asarray(z) - params.d_alpha, params.a, params.b)


def phi_beta(z, params: FlockingParams):
    """Repulsive action function φ_β(z) = ρ_hβ(z/d_β)(σ1(z − d_β) − 1) (Olfati-Saber 2006 §VI)."""
    d_beta = params.d_beta
    return bump(np.asarray(z) / d_beta, params.h_beta) * (sigma_1(np.asarray(z) - d_beta) - 1.0)


# --- neighbourhoods ------------------------------------------------------------------------

def neighbour_pairs(positions, radius: float) -> np.ndarray:
    """Unordered pairs (i, j), i < j, with ‖q_i − q_j‖ < radius: the r-disc graph.

    Args:
        positions: (N, 2) m.
    Returns:
        (P, 2) int array (scipy cKDTree.query_pairs; ``<= radius`` there, boundary pairs
        carry zero weight anyway since ρ_h(1) = 0).
    """
    from scipy.spatial import cKDTree     # here: `herd-ros flock --help` imports no scipy
    positions = np.asarray(positions, dtype=float)
    if len(positions) < 2:
        return np.zeros((0, 2), dtype=np.intp)
    return cKDTree(positions).query_pairs(radius, output_type='ndarray')


def _scatter_pairs(n, i, j, force_on_i):
    """Σ over pairs of an antisymmetric pair force: +f to i, −f to j. (N, 2)."""
    out = np.empty((n, 2))
    for axis in range(2):
        w = force_on_i[:, axis]
        out[:, axis] = np.bincount(i, w, minlength=n) - np.bincount(j, w, minlength=n)
    return out


# --- the three terms -------------------------------------------------------------------------

def alpha_term(positions, velocities, pairs, params: FlockingParams) -> np.ndarray:
    """u^α (N, 2): σ-norm gradient of the pairwise potential plus velocity consensus
    (Olfati-Saber 2006 Algorithms 1 and 3) with gains c1α, c2α."""
    q = np.asarray(positions, dtype=float)
    p = np.asarray(velocities, dtype=float)
    n = len(q)
    if len(pairs) == 0:
        return np.zeros((n, 2))
    i, j = pairs[:, 0], pairs[:, 1]
    dq = q[j] - q[i]
    z = sigma_norm(dq, params.epsilon)
    n_ij = sigma_gradient(dq, params.epsilon)
    a_ij = bump(z / params.r_alpha, params.h_alpha)
    force = (params.c1_alpha * phi_alpha(z, params))[:, None] * n_ij \
        + (params.c2_alpha * a_ij)[:, None] * (p[j] - p[i])
    return _scatter_pairs(n, i, j, force)


def beta_agents(positions, velocities, obstacles: CircularObstacles):
    """Virtual β-agents: projections of each agent on each circular obstacle (Lemma 4).

    Args:
        positions, velocities: (N, 2) agents.
        obstacles: K circles at the current time (centres ``y_k``, radii ``R_k``, velocities).
    Returns:
        (q_hat, p_hat): (N, K, 2) positions on the circles and their velocities,
        ``q̂ = μ q + (1 − μ) y``, ``p̂ = μ P (p − v) + v``, ``μ = R/‖q − y‖``, ``P = I − a aᵀ``.
    """
    q = np.asarray(positions, dtype=float)[:, None, :]
    p = np.asarray(velocities, dtype=float)[:, None, :]
    y = obstacles.centres[None, :, :]
    v = obstacles.velocities[None, :, :]
    offset = q - y
    dist = np.linalg.norm(offset, axis=-1, keepdims=True)
    dist = np.maximum(dist, 1e-12)
    mu = obstacles.radii[None, :, None] / dist
    a_k = offset / dist
    rel = p - v
    rel_tangential = rel - np.sum(rel * a_k, axis=-1, keepdims=True) * a_k
    q_hat = mu * q + (1.0 - mu) * y
    p_hat = mu * rel_tangential + v
    return q_hat, p_hat


def beta_term(positions, velocities, obstacles: CircularObstacles | None,
              params: FlockingParams) -> np.ndarray:
    """u^β (N, 2): repulsion from, and velocity matching with, the β-agents closer than
    r' (Olfati-Saber 2006 §VI, Algorithm 3, gains c1β, c2β)."""
    q = np.asarray(positions, dtype=float)
    n = len(q)
    if obstacles is None or len(obstacles) == 0:
        return np.zeros((n, 2))
    p = np.asarray(velocities, dtype=float)
    q_hat, p_hat = beta_agents(q, p, obstacles)
    dq = q_hat - q[:, None, :]
    dist = np.linalg.norm(dq, axis=-1)
    z = sigma_norm_of_length(dist, params.epsilon)
    active = (dist < params.beta_range)
    b_ik = bump(z / params.d_beta, params.h_beta) * active
    gradient = (params.c1_beta * phi_beta(z, params) * active)[..., None] \
        * sigma_gradient(dq, params.epsilon)
    consensus = (params.c2_beta * b_ik)[..., None] * (p_hat - p[:, None, :])
    return np.sum(gradient + consensus, axis=1)


def neighbourhood_means(values, pairs) -> np.ndarray:
    """Mean of ``values`` (N, D) over N_i ∪ {i} for every agent (report eq. 6)."""
    values = np.asarray(values, dtype=float)
    n = len(values)
    counts = np.ones(n)
    sums = values.copy()
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        counts += np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
        for axis in range(values.shape[1]):
            sums[:, axis] += np.bincount(i, values[j, axis], minlength=n) \
                + np.bincount(j, values[i, axis], minlength=n)
    return sums / counts[:, None]


def gamma_term(positions, velocities, target_position, target_velocity, pairs,
               params: FlockingParams, mode: str | None = None) -> np.ndarray:
    """u^γ (N, 2): navigational feedback to the target ``(q_r, p_r)``.

    * ``plain``: ``−c1γ (q_i − q_r) − c2γ (p_i − p_r)`` (La & Sheng 2009, Olfati-Saber's
      Algorithm 2 with a linear position error);
    * ``global-com``: plus ``−c1mc (q̄ − q_r) − c2mc (p̄ − p_r)``, q̄, p̄ the mean position and
      velocity of all N agents (report eq. 5);
    * ``local-com``: plus ``−c1mc (q̄_i − q_r) − c2mc (p̄_i − p_r)``, means over N_i ∪ {i}
      (report eq. 6): needs only what agent i senses.
    """
    mode = mode or params.gamma_mode
    q = np.asarray(positions, dtype=float)
    p = np.asarray(velocities, dtype=float)
    q_r = np.asarray(target_position, dtype=float).reshape(2)
    p_r = np.asarray(target_velocity, dtype=float).reshape(2)
    u = -params.c1_gamma * (q - q_r) - params.c2_gamma * (p - p_r)
    if mode == 'plain':
        return u
    if mode == 'global-com':
        return (u - params.c1_com * (q.mean(axis=0) - q_r)
                - params.c2_com * (p.mean(axis=0) - p_r))
    if mode == 'local-com':
        means = neighbourhood_means(np.hstack([q, p]), pairs)
        return u - params.c1_com * (means[:, :2] - q_r) - params.c2_com * (means[:, 2:] - p_r)
    raise HerdInputError(f'gamma mode must be one of {", ".join(GAMMA_MODES)} (got {mode!r})')


def flocking_acceleration(positions, velocities, target_position, target_velocity,
                          params: FlockingParams = FlockingParams(),
                          obstacles: CircularObstacles | None = None,
                          pairs: np.ndarray | None = None) -> np.ndarray:
    """Acceleration commands u = u^α + u^β + u^γ for every agent (the whole law, one call).

    This is what a node calls each control period: the fleet's positions and velocities
    (its own robots and every neighbour it hears of), the target, the obstacles at the
    current time and the gains.

    Args:
        positions: (N, 2) m, the agents q_i.
        velocities: (N, 2) m/s, p_i.
        target_position: (2,) m, q_r (γ-agent).
        target_velocity: (2,) m/s, p_r.
        params: gains and constants (``params.gamma_mode`` selects the γ variant).
        obstacles: circles at the current time (centres, radii, velocities), or None.
        pairs: neighbour pairs from :func:`neighbour_pairs` if already computed.
    Returns:
        (N, 2) accelerations, m/s².
    """
    q = np.asarray(positions, dtype=float)
    p = np.asarray(velocities, dtype=float)
    if q.ndim != 2 or q.shape[1] != 2 or p.shape != q.shape:
        raise HerdInputError(f'positions and velocities must both be (N, 2) arrays '
                             f'(got {q.shape} and {p.shape})')
    if pairs is None:
        pairs = neighbour_pairs(q, params.range)
    return (alpha_term(q, p, pairs, params)
            + beta_term(q, p, obstacles, params)
            + gamma_term(q, p, target_position, target_velocity, pairs, params))
