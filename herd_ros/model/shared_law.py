"""A shared interaction law whose parameter count does not grow with the herd.

The pairwise law of Schwager et al. (2007) gives agent i two parameters per neighbour
(θ1_ij, θ2_ij), so p grows with N and a herd of thousands is out of reach. The shared law
keeps their model (eq. 2) but gives every neighbour within a radius r the **same**
attraction/repulsion profile F_i(d), expanded in a radial basis of the distance:

    u_i^{τ+1} = a_i u_i^τ + Σ_{j: d_ij < r} F_i(d_ij) e_ij + g_i(p_i^τ) + w_i^τ
    F_i(d)    = Σ_b c_ib ψ_b(d),   ψ_b(d) = exp(−(d − r_b)² / 2s²) · ½(1 + cos(π d / r))

with e_ij = (p_j − p_i)/d_ij, bump centres r_b = r (b + ½)/B evenly in (0, r), width
s = ⅔ r/B (the ⅔-of-spacing rule of the field basis), and a cosine taper so F vanishes
smoothly at the radius (a neighbour entering the radius does not kick the agent).
F > 0 attracts, F < 0 repels. g_i is the RBF field of :mod:`rbf_field`.

Per agent θ_i = [a_i, c_i1 … c_iB, θu_i1 … θu_iK, θv_i1 … θv_iK], p = 1 + B + 2K whatever N.
The profile c_i is **per agent**, not shared across agents: each agent stays its own
independent regression (so the batched RLS of :mod:`herd_ros.estimation.rls` applies
unchanged and a collar that drops out affects only itself), animals of one herd do differ in
how close they keep to others, and a herd-wide profile is recovered as the mean of the c_i.

**Distinguished agents** (a dog driving sheep, a robot, a leader) can have their **own
profile**: for the agents k of ``own_agents`` the sum above runs over the other neighbours
only, and every agent i gains one more term per distinguished agent,

    + H_ik(d_ik) e_ik,   H_ik(d) = Σ_b h_ikb ψ'_b(d)   (k ≠ i, d_ik < r')

on a basis ψ' of the same form with its own radius r' (a dog moves sheep from farther than
sheep keep to each other). θ_i = [a_i, c_i.., h_i,k1.., h_i,k2.., θu_i.., θv_i..]; the
block of a distinguished agent with itself is zero (it is not fitted). This is how the
interactions with an agent of another kind stay identifiable in a large herd: pooled into
the shared law a dog is one neighbour among fifty and its pull is averaged away; a
pairwise law gives every pair its own parameters, which hours of data do not identify.

Neighbours come from :class:`scipy.spatial.cKDTree` (``query_pairs``), so one snapshot of
N animals costs O(N log N + pairs) rather than O(N²).

Model file (``kind: schwager2007_shared``; the ``model:`` mapping of doc/formats.md)::

    model:
      kind: schwager2007_shared
      dt: 1.0
      frame_id: map
      datum: [lat, lon, alt]          # optional
      agents: [cow_1, cow_2, ...]
      interaction_radius: 60.0        # r (m): neighbours beyond it exert nothing
      profile_centers: [5.0, 15.0, ...]  # r_b (m), B entries
      profile_width: 6.67             # s (m)
      cow_1:
        damping: 0.93
        profile: [c_1, ..., c_B]      # m/s² per unit ψ: F(d) = Σ c_b ψ_b(d)
        rbf_centers_x: [..]           # as in schwager2007
        rbf_centers_y: [..]
        rbf_sigma: [..]
        field_u: [..]
        field_v: [..]
        noise_cov: [qxx, qxy, qyx, qyy]
        theta_se: [..]                # optional, order [damping, profile.., field_u.., field_v..]
                                      # (with own profiles: [damping, profile.., own_profile..,
                                      # field_u.., field_v..])

With distinguished agents the model also has (all three or none)::

      own_profile_agents: [dog]       # the agents k with their own profile
      own_profile_radius: 80.0        # r' (m)
      own_profile_centers: [..]       # r'_b (m), B' entries; width ⅔ of their spacing
      own_profile_width: 8.9          # s' (m)
      cow_1:
        own_profile: [..]             # h_ik, B' per distinguished agent in their order
                                      # (zeros for an agent's block with itself)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from herd_ros.errors import HerdInputError
from herd_ros.model.distance_profile import (  # noqa: F401 (re-exported)
    DEFAULT_PROFILE_SIZE, DEFAULT_RADIUS, DistanceProfile)
from herd_ros.model.model_file import (add_model_meta, check_agent_id, float_list,
                                       load_model_body, read_alignment, read_model_meta)
from herd_ros.model.rbf_field import RbfBasis, agent_fields
from herd_ros.model.herd_place import place_drift
from herd_ros.model.space_use_field import home_drift
from herd_ros.model.velocity_memory import VelocityMemory

KIND = 'schwager2007_shared'
#: Up to this many agents a whole run's interactions are summed over every pair at once.
DENSE_MAX_AGENTS = 200


def neighbor_pairs(positions: np.ndarray, radius: float):
    """Pairs (i < j) closer than ``radius``: index arrays (M,), offsets p_j − p_i (M, 2), d (M,).

    Rows with non-finite positions take no part.
    """
    p = np.asarray(positions, dtype=float)
    ok = np.flatnonzero(np.isfinite(p).all(axis=1))
    if len(ok) < 2:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, np.zeros((0, 2)), np.zeros(0)
    pairs = cKDTree(p[ok]).query_pairs(radius, output_type='ndarray')
    i, j = ok[pairs[:, 0]], ok[pairs[:, 1]]
    off = p[j] - p[i]
    return i, j, off, np.sqrt((off ** 2).sum(-1))


def shared_columns(positions: np.ndarray, rows, profile: DistanceProfile, own=(),
                   own_profile: DistanceProfile | None = None):
    """The shared law's interaction columns — the one builder of them, for the batch fit and
    the selection (one agent over many steps), the RLS (every agent at one step) and the
    model's own evaluation.

    For each step m and agent i of ``rows``: Σ_{j: d_ij < r, j not in own} ψ_b(d_ij) e_ij
    (B columns), then per distinguished agent k of ``own`` (with ``own_profile``)
    ψ'_b(d_ik) e_ik (S·B' columns; zero for k = i, for a missing k and beyond r').

    Args:
        positions: (M, N, 2), NaN = missing (a missing neighbour drops out).
        rows: the agents i (indices).
    Returns:
        (columns (M, R, B + S·B', 2), coincident (M, R): agent i shares its position with
        another agent, d = 0, where e_ij is undefined and its columns are left out).
        A single step of more than :data:`DENSE_MAX_AGENTS` agents takes its pooled pairs
        from a k-d tree; otherwise every pair is formed at once, in chunks.
    """
    p = np.asarray(positions, dtype=float)
    M, n = p.shape[:2]
    rows = np.atleast_1d(np.asarray(rows, dtype=int))
    own = [int(k) for k in own]
    B = profile.size
    Bo = own_profile.size if own and own_profile is not None else 0
    out = np.zeros((M, len(rows), B + len(own) * Bo, 2))
    coincident = np.zeros((M, len(rows)), bool)
    pooled = np.ones(n, bool)
    pooled[own] = False
    if M == 1 and n > DENSE_MAX_AGENTS:
        i, j, off, d = neighbor_pairs(p[0], profile.radius)
        zero = d <= 0
        hit = np.zeros(n, bool)
        hit[i[zero]] = hit[j[zero]] = True
        i, j, off, d = i[~zero], j[~zero], off[~zero], d[~zero]
        w = profile.features(d)[..., None] * (off / d[:, None])[:, None, :]   # (P, B, 2)
        full = np.zeros((n, B, 2))
        np.add.at(full, i, w * pooled[j][:, None, None])      # j acts on i if j is pooled
        np.add.at(full, j, -w * pooled[i][:, None, None])
        out[0, :, :B] = full[rows]
        coincident[0] = hit[rows]
        cols = [own_profile] if Bo else []
        if cols:                                   # S distinguished agents: (R, S) dense
            off = p[0, own][None] - p[0, rows][:, None]
            d = np.sqrt((off ** 2).sum(-1))
            self_ = rows[:, None] == np.asarray(own)[None, :]
            ok = np.isfinite(d) & (d > 0) & ~self_
            coincident[0] |= (np.isfinite(d) & (d <= 0) & ~self_).any(-1)
            with np.errstate(invalid='ignore', divide='ignore'):
                e = np.where(ok[..., None], off / np.where(ok, d, 1.0)[..., None], 0.0)
            h = own_profile.features(np.where(ok, d, np.inf))[..., None] * e[:, :, None, :]
            out[0, :, B:] = h.reshape(len(rows), -1, 2)
        return out, coincident
    rchunk = max(1, int(4_000_000 // max(n * B, 1)))
    for r0 in range(0, len(rows), rchunk):
        rr = rows[r0:r0 + rchunk]
        mchunk = max(1, int(4_000_000 // max(len(rr) * n * B, 1)))
        not_self = np.arange(n)[None, :] != rr[:, None]                  # (R, N)
        for m0 in range(0, M, mchunk):
            q = p[m0:m0 + mchunk]
            off = q[:, None, :, :] - q[:, rr, None, :]                   # [m, r, j] = p_j − p_i
            d = np.sqrt((off ** 2).sum(-1))
            with np.errstate(invalid='ignore'):
                near = np.isfinite(d) & (d > 0) & not_self
                coincident[m0:m0 + mchunk, r0:r0 + len(rr)] = (
                    np.isfinite(d) & (d <= 0) & not_self).any(-1)
            with np.errstate(invalid='ignore', divide='ignore'):
                e = np.where(near[..., None], off / np.where(near, d, 1.0)[..., None], 0.0)
            psi = profile.features(np.where(near & pooled, d, np.inf))     # (m, R, N, B)
            block = out[m0:m0 + mchunk, r0:r0 + len(rr)]
            block[:, :, :B] = np.einsum('mrjb,mrjk->mrbk', psi, e)
            for s, k in enumerate(own[:len(own) if Bo else 0]):
                h = own_profile.features(np.where(near[:, :, k], d[:, :, k], np.inf))
                block[:, :, B + s * Bo:B + (s + 1) * Bo] = h[..., None] * e[:, :, k, None, :]
    return out, coincident


def interaction_features(positions: np.ndarray, profile: DistanceProfile, own=()):
    """The pooled columns Σ_{j: d_ij<r} ψ_b(d_ij) e_ij of every agent at one step, (N, 2) ->
    (N, B, 2), and a valid mask (a finite position, no coincident neighbour):
    :func:`shared_columns`. ``own``: the distinguished agents, left out of every sum."""
    p = np.asarray(positions, dtype=float)
    cols, coincident = shared_columns(p[None], np.arange(p.shape[0]), profile, own)
    return cols[0], np.isfinite(p).all(axis=1) & ~coincident[0]


def shared_rows(p_prev: np.ndarray, p_cur: np.ndarray, dt: float, profile: DistanceProfile,
                basis: RbfBasis, own=(), own_profile: DistanceProfile | None = None):
    """Regression rows of u^{τ+1} for all agents from p^τ (``p_prev``) and p^{τ+1} (``p_cur``).

    Returns H (N, 2, p) with rows [u, Σψ e, ψ'e.., φ, 0] (x) and [u, Σψ e, ψ'e.., 0, φ] (y),
    p = 1 + B + S·B' + 2K (S = ``len(own)`` distinguished agents; the interaction columns
    of :func:`shared_columns`), and valid (N,) (finite positions, no coincident neighbour).
    """
    p0 = np.asarray(p_prev, dtype=float)
    u = (np.asarray(p_cur, dtype=float) - p0) / dt
    n, K = p0.shape[0], basis.size
    cols, coincident = shared_columns(p0[None], np.arange(n), profile, own, own_profile)
    C = cols.shape[2]
    phi = basis.features(np.nan_to_num(p0))
    H = np.zeros((n, 2, 1 + C + 2 * K))
    H[:, :, 0] = u
    H[:, 0, 1:1 + C] = cols[0, :, :, 0]
    H[:, 1, 1:1 + C] = cols[0, :, :, 1]
    H[:, 0, 1 + C:1 + C + K] = phi
    H[:, 1, 1 + C + K:] = phi
    valid = np.isfinite(p0).all(axis=1) & np.isfinite(u).all(axis=1) & ~coincident[0]
    return H, valid


@dataclass
class SharedLawModel(VelocityMemory):
    """A herd under the shared law; same surface as :class:`HerdModel` (simulate, predict).

    Attributes: damping (N,), profile_coef (N, B), bases (one :class:`RbfBasis` per agent),
    field_u/field_v (lists of (K_i,)), noise_cov (N, 2, 2), theta_se (optional list);
    distinguished agents: own_agents (S names), own_profile (ψ'), own_coef (N, S, B').
    """

    agents: list[str]
    dt: float
    profile: DistanceProfile
    damping: np.ndarray
    profile_coef: np.ndarray
    bases: list
    field_u: list
    field_v: list
    noise_cov: np.ndarray
    theta_se: list | None = None
    frame_id: str = 'map'
    datum: list | None = None
    meta: dict = field(default_factory=dict)
    own_agents: list = field(default_factory=list)
    own_profile: DistanceProfile | None = None
    own_coef: np.ndarray | None = None
    alignment: object = None        # a VelocityAlignment (:mod:`alignment`) or None

    kind = KIND

    def __post_init__(self):
        n = len(self.agents)
        self.own_agents = [str(a) for a in self.own_agents]
        unknown = [a for a in self.own_agents if a not in self.agents]
        if unknown:
            raise HerdInputError(f'own-profile agent(s) {", ".join(unknown)} are not in the '
                                 f'herd ({", ".join(self.agents)})')
        if len(set(self.own_agents)) != len(self.own_agents):
            raise HerdInputError('own-profile agents are listed twice')
        self.own_index = np.array([self.agents.index(a) for a in self.own_agents], dtype=int)
        if self.own_agents:
            if self.own_profile is None:
                raise HerdInputError('own-profile agents need an own_profile basis')
            self.own_coef = np.asarray(self.own_coef, dtype=float).reshape(
                n, len(self.own_agents), self.own_profile.size)
        else:
            self.own_coef = np.zeros((n, 0, 0))
        self.damping = np.asarray(self.damping, dtype=float).reshape(n)
        self.profile_coef = np.asarray(self.profile_coef, dtype=float).reshape(n, self.profile.size)
        self.noise_cov = np.asarray(self.noise_cov, dtype=float).reshape(n, 2, 2)
        if not (self.dt > 0):
            raise HerdInputError(f'model dt must be positive, got {self.dt}')
        if not (len(self.bases) == len(self.field_u) == len(self.field_v) == n):
            raise HerdInputError('shared-law model needs one basis and field per agent')
        kmax = max([b.size for b in self.bases] + [1])
        self._centers = np.zeros((n, kmax, 2))
        self._sigma = np.ones((n, kmax))
        self._coef = np.zeros((n, kmax, 2))
        for i, b in enumerate(self.bases):  # packing once at load time, not per step
            k = b.size
            if len(self.field_u[i]) != k or len(self.field_v[i]) != k:
                raise HerdInputError(f'agent {self.agents[i]}: field_u/field_v need {k} entries')
            self._centers[i, :k], self._sigma[i, :k] = b.centers, b.sigma
            self._coef[i, :k, 0], self._coef[i, :k, 1] = self.field_u[i], self.field_v[i]

    @property
    def n_agents(self) -> int:
        """Number of agents N."""
        return len(self.agents)

    def theta(self, i: int) -> np.ndarray:
        """θ_i = [damping, profile.., own_profile.., field_u.., field_v..]."""
        return np.concatenate([[self.damping[i]], self.profile_coef[i],
                               self.own_coef[i].ravel(), self.field_u[i], self.field_v[i]])

    def parameter_names(self, i: int) -> list[str]:
        """The names of :meth:`theta`'s entries: profile[b], own_profile[agent][b],
        field_u[k], field_v[k]."""
        own = [f'own_profile[{self.agents[k]}][{b}]' for k in self.own_index
               for b in range(self.own_coef.shape[-1])]
        K = len(self.field_u[i])
        return (['damping'] + [f'profile[{b}]' for b in range(self.profile_coef.shape[1])]
                + own + [f'field_u[{k}]' for k in range(K)]
                + [f'field_v[{k}]' for k in range(K)])

    def interaction(self, positions: np.ndarray) -> np.ndarray:
        """Σ_{j: d<r} F_i(d_ij) e_ij (+ Σ_k H_ik(d_ik) e_ik over the distinguished agents)
        for positions (N, 2) or (T, N, 2): the columns of :func:`shared_columns` times θ."""
        p = np.asarray(positions, dtype=float)
        if not (self.profile_coef.any() or self.own_coef.any()):
            return np.zeros(p.shape)               # no interaction kept (a damping-only fit)
        q = p if p.ndim == 3 else p[None]
        n = q.shape[1]
        coef = np.concatenate([self.profile_coef, self.own_coef.reshape(n, -1)], axis=1)
        out = np.empty(q.shape)
        chunk = max(1, int(2_000_000 // max(n * coef.shape[1] * 2, 1)))
        for t0 in range(0, len(q), chunk):
            cols, _ = shared_columns(q[t0:t0 + chunk], np.arange(n), self.profile,
                                     self.own_index, self.own_profile)
            out[t0:t0 + chunk] = np.einsum('tnck,nc->tnk', cols, coef)
        return out if p.ndim == 3 else out[0]

    def environment(self, positions: np.ndarray, compiled: bool | None = None,
                    counted: np.ndarray | None = None,
                    share: np.ndarray | None = None) -> np.ndarray:
        """g_i(p_i) for positions (..., N, 2): the RBF field (plus the space-use home pull and
        the pull to the agent's place in the herd, its others' centroid over the ``counted``
        agents (N,) when given, and with ``share`` (N,) that share of its linear pull inside
        each range too)."""
        return (agent_fields(positions, self._centers, self._sigma, self._coef, compiled)
                + home_drift(self.meta, positions)
                + place_drift(self.meta, positions, counted, share))

    def drift(self, positions, compiled: bool | None = None):
        """Σ_j F(d_ij) e_ij (+ own profiles) + g_i(p_i) for every agent: (N, 2) -> (N, 2)."""
        return self.interaction(positions) + self.environment(positions, compiled)

    def next_velocity(self, velocity, positions,
                      compiled: bool | None = None):
        """E[u^{τ+1}] = a_i u^τ + Σ F e + g (+ the alignment A_i, :mod:`alignment`)."""
        from herd_ros.model.alignment import alignment_term
        return (self.damping[:, None] * velocity + self.drift(positions, compiled)
                + alignment_term(self.alignment, positions, velocity))

    def describe(self) -> str:
        """A few lines: kind, agents, radius, profile terms, own profiles."""
        lines = [f'SharedLawModel({KIND}, {self.n_agents} agents, dt={self.dt:g} s, radius '
                 f'{self.profile.radius:g} m, {self.profile.size} profile terms)']
        if self.own_agents:
            lines.append(f'  own profiles of {", ".join(self.own_agents)} (radius '
                         f'{self.own_profile.radius:g} m, {self.own_profile.size} terms)')
        for i, a in enumerate(self.agents[:20]):
            lines.append(f'  {a}: damping {self.damping[i]:.4f}; {self.bases[i].size} centres')
        return '\n'.join(lines)

    __str__ = describe


# -- model file ------------------------------------------------------------------------------
def shared_model_to_dict(model: SharedLawModel) -> dict:
    """The ``model:`` mapping of a ``schwager2007_shared`` parameters file."""
    body = {'kind': KIND, 'dt': float(model.dt), 'frame_id': model.frame_id}
    if model.datum is not None:
        body['datum'] = float_list(model.datum)
    body['agents'] = [check_agent_id(a) for a in model.agents]
    body['interaction_radius'] = float(model.profile.radius)
    body['profile_centers'] = float_list(model.profile.centers)
    body['profile_width'] = float(model.profile.width)
    if model.own_agents:
        body['own_profile_agents'] = list(model.own_agents)
        body['own_profile_radius'] = float(model.own_profile.radius)
        body['own_profile_centers'] = float_list(model.own_profile.centers)
        body['own_profile_width'] = float(model.own_profile.width)
    for i, a in enumerate(model.agents):
        b = model.bases[i]
        if b.size == 0:
            raise HerdInputError(f'agent {a} has no field centre; a ROS parameter array cannot '
                                 f'be empty')
        entry = {'damping': float(model.damping[i]), 'profile': float_list(model.profile_coef[i]),
                 'rbf_centers_x': float_list(b.centers[:, 0]),
                 'rbf_centers_y': float_list(b.centers[:, 1]), 'rbf_sigma': float_list(b.sigma),
                 'field_u': float_list(model.field_u[i]), 'field_v': float_list(model.field_v[i]),
                 'noise_cov': float_list(model.noise_cov[i])}
        if model.own_agents:
            entry['own_profile'] = float_list(model.own_coef[i].ravel())
        if model.theta_se is not None:
            entry['theta_se'] = float_list(model.theta_se[i])
        body[a] = entry
    add_model_meta(body, model)
    return body


def shared_model_from_dict(body: dict, source: str = 'model') -> SharedLawModel:
    """Inverse of :func:`shared_model_to_dict`; errors name the source and key."""
    def need(mapping, key, where):
        if key not in mapping:
            raise HerdInputError(f'{source}: {where} has no key {key!r}')
        return mapping[key]

    if body.get('kind') != KIND:
        raise HerdInputError(f'{source}: model kind {body.get("kind")!r} is not {KIND!r}')
    try:
        profile = DistanceProfile(float(need(body, 'interaction_radius', 'model')),
                                  tuple(float(c) for c in need(body, 'profile_centers', 'model')),
                                  float(need(body, 'profile_width', 'model')))
        agents = [str(a) for a in need(body, 'agents', 'model')]
        own_keys = ('own_profile_agents', 'own_profile_radius', 'own_profile_centers',
                    'own_profile_width')
        have = [k for k in own_keys if k in body]
        if have and len(have) != len(own_keys):
            missing = [k for k in own_keys if k not in body]
            raise HerdInputError(f'{source}: model has {have[0]!r} but not {missing[0]!r} '
                                 f'(own profiles need all of {", ".join(own_keys)})')
        own_agents = [str(a) for a in body.get('own_profile_agents', [])]
        own_profile = (DistanceProfile(float(body['own_profile_radius']),
                                       tuple(float(c) for c in body['own_profile_centers']),
                                       float(body['own_profile_width']))
                       if own_agents else None)
        own_size = len(own_agents) * (own_profile.size if own_profile else 0)
        damping, coef, bases, fu, fv, q, se, own = [], [], [], [], [], [], [], []
        for a in agents:
            e = need(body, a, 'model')
            for key in ('damping', 'profile', 'rbf_centers_x', 'rbf_centers_y', 'rbf_sigma',
                        'field_u', 'field_v', 'noise_cov'):
                need(e, key, f'model.{a}')
            if len(e['profile']) != profile.size:
                raise HerdInputError(f'{source}: model.{a}.profile needs {profile.size} '
                                     f'entries (one per profile centre)')
            if own_agents:
                h = np.asarray(need(e, 'own_profile', f'model.{a}'), float)
                if h.size != own_size:
                    raise HerdInputError(f'{source}: model.{a}.own_profile needs {own_size} '
                                         f'entries ({len(own_agents)} agents × '
                                         f'{own_profile.size} centres)')
                own.append(h)
            damping.append(float(e['damping']))
            coef.append(np.asarray(e['profile'], float))
            bases.append(RbfBasis(np.column_stack([np.asarray(e['rbf_centers_x'], float),
                                                   np.asarray(e['rbf_centers_y'], float)]),
                                  np.asarray(e['rbf_sigma'], float)))
            fu.append(np.asarray(e['field_u'], float))
            fv.append(np.asarray(e['field_v'], float))
            q.append(np.asarray(e['noise_cov'], float).reshape(2, 2))
            se.append(np.asarray(e['theta_se'], float) if 'theta_se' in e else None)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, HerdInputError):
            raise
        raise HerdInputError(f'{source}: malformed shared-law model ({exc})') from None
    return SharedLawModel(agents=agents, dt=float(need(body, 'dt', 'model')), profile=profile,
                          damping=damping, profile_coef=np.array(coef), bases=bases,
                          field_u=fu, field_v=fv, noise_cov=np.array(q),
                          theta_se=None if any(s is None for s in se) else se,
                          frame_id=str(body.get('frame_id', 'map')), datum=body.get('datum'),
                          meta=read_model_meta(body, len(agents), source),
                          own_agents=own_agents, own_profile=own_profile,
                          own_coef=np.array(own) if own_agents else None,
                          alignment=read_alignment(body, agents, source))


def save_shared_model(model: SharedLawModel, path, selection: dict | None = None):
    """Write the ``schwager2007_shared`` model file atomically (``selection``: see
    :func:`herd_ros.model.model_file.selection_entry`); :func:`herd_ros.model.kinds.save`."""
    from herd_ros.model.kinds import save
    return save(model, path, selection)


def load_shared_model(path) -> SharedLawModel:
    """The shared-law model in the model file ``path``."""
    return shared_model_from_dict(load_model_body(path), source=str(path))


def make_shared_truth(n_agents: int, seed=0, profile: DistanceProfile | None = None,
                      basis: RbfBasis | None = None, field_fn=None, dt: float = 1.0,
                      noise_std: float = 0.05, damping_range=(0.90, 0.97),
                      spacing=20.0, strength=0.02) -> SharedLawModel:
    """A known-truth shared-law herd: every agent repels below ``spacing`` m and attracts beyond
    (F(d) ≈ strength·(d − spacing)/spacing, projected on the profile basis), damping drawn
    uniformly, and ``field_fn(centres) -> (K, 2)`` coefficients of the field (default none)."""
    rng = np.random.default_rng(seed)
    profile = profile or DistanceProfile.even()
    agents = [f'agent_{k + 1}' for k in range(n_agents)]
    d = np.linspace(0.5, profile.radius * 0.999, 400)
    target = strength * (d - spacing) / spacing * 0.5 * (1 + np.cos(np.pi * d / profile.radius))
    c, *_ = np.linalg.lstsq(profile.features(d), target, rcond=None)
    basis = basis or RbfBasis(np.zeros((1, 2)), np.ones(1) * 1e3)
    coef_field = (np.zeros((basis.size, 2)) if field_fn is None
                  else np.asarray(field_fn(basis.centers), float))
    gains = rng.uniform(0.8, 1.2, size=n_agents)
    return SharedLawModel(
        agents=agents, dt=dt, profile=profile,
        damping=rng.uniform(*damping_range, size=n_agents),
        profile_coef=np.outer(gains, c), bases=[basis] * n_agents,
        field_u=[coef_field[:, 0]] * n_agents, field_v=[coef_field[:, 1]] * n_agents,
        noise_cov=np.tile(np.eye(2) * noise_std ** 2, (n_agents, 1, 1)))
