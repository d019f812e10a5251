"""The herd model of Schwager, Anderson and Rus (FSR 2007), vectorized over agents and time.

Per agent i, with a constant step Δt (eqs. 2–4, 8 of the paper):

    u_i^{τ+1} = a_i u_i^τ + Σ_{j≠i} f_ij(p_i^τ, p_j^τ) + g_i(p_i^τ) + w_i^τ
    p_i^{τ+1} = p_i^τ + Δt u_i^τ
    f_ij = (θ1_ij − θ2_ij / ‖p_j − p_i‖) (p_j − p_i) / ‖p_j − p_i‖
    g_i(p) = Σ_k [θu_ik, θv_ik] φ_k(p)                       (see :mod:`rbf_field`)

Only positions are observed, so u^τ = (p^{τ+1} − p^τ)/Δt and the one-step predictor is

    p̂^{τ+2} = p^{τ+1} + Δt (a_i u^τ + Σ_j f_ij^τ + g_i^τ)              (eq. 8)

f_ij is repulsive below the equilibrium distance θ2_ij/θ1_ij and attractive beyond it.
w_i is zero-mean noise with covariance Q_i (``noise_cov``).

:class:`HerdModel` holds one :class:`AgentLaw` per agent and evaluates the deterministic part
for the whole herd at once: ``drift(p)`` (..., N, 2) -> Σf + g (..., N, 2).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.model.alignment import VelocityAlignment, alignment_term
from herd_ros.model.rbf_field import RbfBasis, agent_fields
from herd_ros.model.herd_place import place_drift
from herd_ros.model.space_use_field import home_drift
from herd_ros.model.velocity_memory import VelocityMemory

KIND = 'schwager2007'


@dataclass
class AgentLaw:
    """The learned law of one agent: θ_i = [a_i, θ1_i·, θ2_i·, θu_i·, θv_i·] and Q_i."""

    damping: float
    neighbors: list[str]
    theta1: np.ndarray
    theta2: np.ndarray
    basis: RbfBasis
    field_u: np.ndarray
    field_v: np.ndarray
    noise_cov: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    theta_se: np.ndarray | None = None

    def __post_init__(self):
        self.theta1 = np.asarray(self.theta1, dtype=float).ravel()
        self.theta2 = np.asarray(self.theta2, dtype=float).ravel()
        self.field_u = np.asarray(self.field_u, dtype=float).ravel()
        self.field_v = np.asarray(self.field_v, dtype=float).ravel()
        self.noise_cov = np.asarray(self.noise_cov, dtype=float).reshape(2, 2)
        if self.theta_se is not None:
            self.theta_se = np.asarray(self.theta_se, dtype=float).ravel()
        n = len(self.neighbors)
        if len(self.theta1) != n or len(self.theta2) != n:
            raise HerdInputError(f'theta1/theta2 need one entry per neighbour ({n}), got '
                                 f'{len(self.theta1)}/{len(self.theta2)}')
        k = self.basis.size
        if len(self.field_u) != k or len(self.field_v) != k:
            raise HerdInputError(f'field_u/field_v need one entry per centre ({k}), got '
                                 f'{len(self.field_u)}/{len(self.field_v)}')

    @property
    def theta(self) -> np.ndarray:
        """θ_i in the order of doc/formats.md: [damping, theta1.., theta2.., field_u..,
        field_v..]."""
        return np.concatenate([[self.damping], self.theta1, self.theta2,
                               self.field_u, self.field_v])

    @property
    def parameter_names(self) -> list[str]:
        """The names of θ_i's entries, in order."""
        return (['damping'] + [f'theta1[{j}]' for j in self.neighbors]
                + [f'theta2[{j}]' for j in self.neighbors]
                + [f'field_u[{k}]' for k in range(self.basis.size)]
                + [f'field_v[{k}]' for k in range(self.basis.size)])

    def equilibrium_distance(self) -> np.ndarray:
        """d* = θ2_ij / θ1_ij where f_ij vanishes (NaN where θ1_ij ≤ 0)."""
        with np.errstate(divide='ignore', invalid='ignore'):
            return np.where(self.theta1 > 0, self.theta2 / self.theta1, np.nan)


def interaction_force(theta1, theta2, distance):
    """Magnitude of f_ij along (p_j − p_i)/d: θ1 − θ2/d (eq. 3); positive = attraction."""
    return np.asarray(theta1) - np.asarray(theta2) / np.asarray(distance)


def pairwise_geometry(positions: np.ndarray):
    """Offsets p_j − p_i (..., N, N, 2), distances (..., N, N) and unit vectors.

    The diagonal (i = j) has distance ``inf`` and unit vector 0, so every pairwise term
    vanishes there without special cases.
    """
    p = np.asarray(positions, dtype=float)
    offset = p[..., None, :, :] - p[..., :, None, :]
    dist = np.sqrt(offset[..., 0] ** 2 + offset[..., 1] ** 2)
    n = np.arange(p.shape[-2])
    dist[..., n, n] = np.inf
    with np.errstate(invalid='ignore', divide='ignore'):
        unit = offset / dist[..., None]
    return offset, dist, unit


@dataclass
class HerdModel(VelocityMemory):
    """A learned herd: the laws of all agents on one clock ``dt`` (s) in frame ``frame_id``;
    ``predict_one_step`` and ``residuals`` (eq. 8) from :class:`VelocityMemory`."""

    agents: list[str]
    dt: float
    laws: dict[str, AgentLaw]
    frame_id: str = 'map'
    datum: list[float] | None = None
    meta: dict = field(default_factory=dict)
    alignment: VelocityAlignment | None = None

    def __post_init__(self):
        missing = [a for a in self.agents if a not in self.laws]
        if missing:
            raise HerdInputError(f'model has no law for agent(s) {", ".join(missing)}')
        if not (self.dt > 0):
            raise HerdInputError(f'model dt must be positive, got {self.dt}')
        self._pack()

    # -- vectorized parameter arrays ------------------------------------------------------
    def _pack(self):
        n = len(self.agents)
        index = {a: k for k, a in enumerate(self.agents)}
        self.damping = np.array([self.laws[a].damping for a in self.agents])
        self.theta1 = np.zeros((n, n))
        self.theta2 = np.zeros((n, n))
        for i, a in enumerate(self.agents):
            law = self.laws[a]
            for j_name, t1, t2 in zip(law.neighbors, law.theta1, law.theta2):
                if j_name not in index:
                    continue  # a neighbour not in this herd exerts nothing
                self.theta1[i, index[j_name]] = t1
                self.theta2[i, index[j_name]] = t2
        kmax = max([self.laws[a].basis.size for a in self.agents] + [1])
        self._centers = np.zeros((n, kmax, 2))
        self._sigma = np.ones((n, kmax))
        self._coef = np.zeros((n, kmax, 2))
        for i, a in enumerate(self.agents):
            law = self.laws[a]
            k = law.basis.size
            self._centers[i, :k] = law.basis.centers
            self._sigma[i, :k] = law.basis.sigma
            self._coef[i, :k, 0] = law.field_u
            self._coef[i, :k, 1] = law.field_v
        self.noise_cov = np.stack([self.laws[a].noise_cov for a in self.agents])

    @property
    def n_agents(self) -> int:
        """Number of agents N."""
        return len(self.agents)

    # -- the deterministic part of eq. 2 --------------------------------------------------
    def interaction(self, positions: np.ndarray) -> np.ndarray:
        """Σ_j f_ij for every agent: positions (..., N, 2) -> (..., N, 2). A missing
        neighbour (NaN position) drops out of the sum."""
        if not (self.theta1.any() or self.theta2.any()):
            return np.zeros(np.shape(positions))   # no pair term kept (a damping-only fit)
        _, dist, unit = pairwise_geometry(positions)
        with np.errstate(invalid='ignore'):
            mag = self.theta1 - self.theta2 / dist  # (..., N, N); diagonal: 0 - 0/inf = 0
            terms = mag[..., None] * unit
        return np.where(np.isfinite(terms), terms, 0.0).sum(-2)

    def environment(self, positions: np.ndarray, compiled: bool | None = None,
                    counted: np.ndarray | None = None,
                    share: np.ndarray | None = None) -> np.ndarray:
        """g_i(p_i) for every agent: positions (..., N, 2) -> (..., N, 2); the RBF field plus,
        in a long-run model, the space-use home pull (S2) of :mod:`space_use_field` and the
        pull to the agent's place in the herd (P1) of :mod:`herd_place`, its others'
        centroid over the ``counted`` agents (N,) when given and, with ``share`` (N,),
        that share of the linear pull inside each range too
        (:func:`~herd_ros.model.space_use_field.edge_pull`)."""
        return (agent_fields(positions, self._centers, self._sigma, self._coef, compiled)
                + home_drift(self.meta, positions)
                + place_drift(self.meta, positions, counted, share))

    def drift(self, positions: np.ndarray, compiled: bool | None = None) -> np.ndarray:
        """Σ_j f_ij(p) + g_i(p_i) for every agent (..., N, 2)."""
        return self.interaction(positions) + self.environment(positions, compiled)

    def next_velocity(self, velocity: np.ndarray, positions: np.ndarray,
                      compiled: bool | None = None) -> np.ndarray:
        """E[u^{τ+1}] = a_i u^τ + Σ f + g (eq. 2 without noise) + the alignment A_i when the
        model has one (:mod:`alignment`); shapes (..., N, 2). With a velocity memory κ < 1,
        ``velocity`` is the mean ū^τ (:mod:`velocity_memory`)."""
        return (self.damping[:, None] * velocity + self.drift(positions, compiled)
                + alignment_term(self.alignment, positions, velocity))

    def describe(self) -> str:
        """A readable summary (as ``print(model)`` gives)."""
        lines = [f'HerdModel({KIND}, {self.n_agents} agents, dt={self.dt:g} s, '
                 f'frame {self.frame_id})']
        for a in self.agents:
            law = self.laws[a]
            se = law.theta_se
            dmp = f'{law.damping:.4f}' + (f' ± {se[0]:.4f}' if se is not None else '')
            deq = ', '.join(f'{j}:{d:.1f} m' for j, d in
                            zip(law.neighbors, law.equilibrium_distance()))
            lines.append(f'  {a}: damping {dmp}; {law.basis.size} field centres; '
                         f'equilibrium distance {deq or "-"}')
        return '\n'.join(lines)

    __str__ = describe
