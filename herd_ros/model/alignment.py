"""Alignment: each animal matches its neighbours' velocity, with a learned distance kernel.

The herd law (Schwager, Anderson & Rus 2007, eq. 2) acts through relative positions only.
Flocks and herds on the move also match their neighbours' velocity — the consensus term
of Olfati-Saber's flocking (2006, eq. 23), the zone of orientation of Couzin et al. (2002),
Reynolds' alignment. Written as a term of eq. 2 with a kernel learned from data in the
manner of Lu, Maggioni & Tang (PNAS 116:14424, 2019), who learn the interaction kernel of
a first-order system from the weighted mean of neighbour differences:

    u_i^{τ+1} = a_i u_i^τ + Σ_j f_ij + g_i(p_i) + A_i^τ + w_i^τ
    A_i^τ     = (1/|N_i|) Σ_{j ∈ N_i} K_i(d_ij) (u_j^τ − u_i^τ)
    K_i(d)    = Σ_b w_ib ψ_b(d)

with ψ_b the radial bumps of the shared law (:class:`~herd_ros.model.shared_law
.DistanceProfile`: Gaussians evenly in (0, r) times a cosine taper that vanishes at r) and
N_i the neighbourhood of agent i at step τ:

* ``'radius'`` — every agent closer than r (a *metric* neighbourhood, Couzin et al. 2002);
* ``'nearest'`` — the k nearest agents within r (a *topological* neighbourhood, Ballerini et
  al., PNAS 105:1232, 2008: starlings keep to their 6–7 nearest whatever the density).

A missing neighbour (no position or no velocity) is not in N_i; an agent with an empty
neighbourhood feels nothing. A_i is linear in w_i, so the columns
``(1/|N_i|) Σ_j ψ_b(d_ij) (u_j − u_i)`` (one per bump, x and y rows) join the regression of
agent i; K_i > 0 pulls the agent's velocity towards its neighbours'. With the velocity
memory of :mod:`velocity_memory` the velocities are the smoothed ū (the same the damping
acts on).

:func:`alignment_columns` is the one builder of those columns — the batch fit, the
selection, the RLS and the model's own evaluation (:meth:`VelocityAlignment
.acceleration`) read it. Plain numpy; no ROS.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.model.distance_profile import DistanceProfile

NEIGHBOURHOODS = ('radius', 'nearest')
#: bumps of the kernel
DEFAULT_SIZE = 4
#: neighbours of the topological neighbourhood (Ballerini et al. 2008)
DEFAULT_NEAREST = 7
#: a single step of more than this many agents takes its neighbours from a k-d tree
SPARSE_FROM_AGENTS = 200


def alignment_columns(positions: np.ndarray, velocities: np.ndarray, rows,
                      profile: DistanceProfile, neighbourhood: str = 'radius',
                      nearest: int = DEFAULT_NEAREST) -> np.ndarray:
    """(1/|N_i|) Σ_{j ∈ N_i} ψ_b(d_ij) (u_j − u_i) for each step m and agent i of ``rows``
    (module docstring).

    Args:
        positions, velocities: (M, N, 2) p^τ and u^τ (or ū^τ), NaN = missing.
        rows: the agents i (indices).
        profile: the bumps ψ_b over the radius r.
        neighbourhood: 'radius' or 'nearest' (the ``nearest`` closest within r).
    Returns:
        (M, R, B, 2); zero where agent i is missing or has no neighbour.
    """
    if neighbourhood not in NEIGHBOURHOODS:
        raise HerdInputError(f'alignment neighbourhood must be one of {NEIGHBOURHOODS}, '
                             f'got {neighbourhood!r}')
    p = np.asarray(positions, dtype=float)
    u = np.asarray(velocities, dtype=float)
    M, n = p.shape[:2]
    rows = np.atleast_1d(np.asarray(rows, dtype=int))
    B = profile.size
    out = np.zeros((M, len(rows), B, 2))
    usable = np.isfinite(p).all(-1) & np.isfinite(u).all(-1)              # (M, N)
    if M == 1 and n > SPARSE_FROM_AGENTS:
        out[0] = _sparse_columns(p[0], u[0], usable[0], rows, profile, neighbourhood,
                                 int(nearest))
        return out
    if M == 1 and neighbourhood == 'radius' and len(rows) == n:
        out[0] = _one_step_columns(p[0], u[0], usable[0], profile)
        return out
    rchunk = max(1, int(4_000_000 // max(n * B, 1)))
    for r0 in range(0, len(rows), rchunk):
        rr = rows[r0:r0 + rchunk]
        not_self = np.arange(n)[None, :] != rr[:, None]                  # (R, N)
        mchunk = max(1, int(4_000_000 // max(len(rr) * n * B, 1)))
        for m0 in range(0, M, mchunk):
            q, v, ok = p[m0:m0 + mchunk], u[m0:m0 + mchunk], usable[m0:m0 + mchunk]
            off = q[:, None, :, :] - q[:, rr, None, :]                   # [m, r, j]
            with np.errstate(invalid='ignore'):
                d = np.sqrt((off ** 2).sum(-1))
                nb = ok[:, None, :] & ok[:, rr, None] & not_self & (d > 0) \
                    & (d < profile.radius)
            if neighbourhood == 'nearest':
                dd = np.where(nb, d, np.inf)
                k = min(int(nearest), n - 1)
                if k < n - 1:
                    cut = np.partition(dd, k - 1, axis=-1)[..., k - 1:k]  # k-th distance
                    nb &= dd <= cut
            count = nb.sum(-1)                                            # (m, R)
            psi = profile.features(np.where(nb, d, np.inf))               # (m, R, N, B)
            du = np.where(nb[..., None], v[:, None, :, :] - v[:, rr, None, :], 0.0)
            cols = np.einsum('mrjb,mrjk->mrbk', psi, du)
            out[m0:m0 + mchunk, r0:r0 + len(rr)] = cols / np.maximum(count, 1)[..., None,
                                                                                None]
    return out


def _one_step_columns(p, u, usable, profile):
    """:func:`alignment_columns` of every agent at one step (the RLS's case), the radius
    neighbourhood: Σ_j ψ_b(d_ij)(u_j − u_i) = (Ψ_i u)_b − (Σ_j ψ_b(d_ij)) u_i, without forming
    the velocity differences. (N, B, 2)."""
    off = p[None, :, :] - p[:, None, :]
    d = np.sqrt(np.einsum('ijk,ijk->ij', off, off))
    nb = (d < profile.radius) & (d > 0) & usable[:, None] & usable[None, :]
    psi = profile.features(np.where(nb, d, profile.radius))       # ψ(r) = 0: not counted
    uz = np.where(usable[:, None], u, 0.0)
    cols = np.matmul(psi.transpose(0, 2, 1), uz) - psi.sum(axis=1)[..., None] * uz[:, None, :]
    return cols / np.maximum(nb.sum(axis=-1), 1)[:, None, None]


def _sparse_columns(p, u, usable, rows, profile, neighbourhood, nearest):
    """:func:`alignment_columns` of one step of a large herd: the neighbours from a k-d
    tree (the same sums, without forming every pair): (R, B, 2)."""
    from scipy.spatial import cKDTree
    n = len(p)
    B = profile.size
    ok = np.flatnonzero(usable)
    full = np.zeros((n, B, 2))
    count = np.zeros(n)
    if len(ok) >= 2:
        tree = cKDTree(p[ok])
        # radius: each pair once (ψ(d) is shared, Δu opposite: it counts for both agents);
        # nearest: the pairs i → j of each agent's k nearest
        symmetric = neighbourhood == 'radius'
        if symmetric:
            pairs = tree.query_pairs(profile.radius, output_type='ndarray')
            i, j = ok[pairs[:, 0]], ok[pairs[:, 1]]
        else:
            k = min(nearest, len(ok) - 1)
            d, idx = tree.query(p[ok], k=k + 1, distance_upper_bound=profile.radius)
            found = np.isfinite(d[:, 1:])                   # column 0: the agent itself
            i, j = np.repeat(ok, k)[found.ravel()], ok[idx[:, 1:][found]]
        d = np.sqrt(((p[j] - p[i]) ** 2).sum(-1))
        keep = d > 0
        i, j, d = i[keep], j[keep], d[keep]
        w = profile.features(d)[..., None] * (u[j] - u[i])[:, None, :]     # (P, B, 2)
        for b in range(B):
            for k in range(2):
                full[:, b, k] = np.bincount(i, w[:, b, k], minlength=n)
                if symmetric:
                    full[:, b, k] -= np.bincount(j, w[:, b, k], minlength=n)
        count = np.bincount(i, minlength=n) + (np.bincount(j, minlength=n) if symmetric
                                               else 0)
    return (full / np.maximum(count, 1)[:, None, None])[rows]


@dataclass(frozen=True)
class AlignmentKernel:
    """The basis and neighbourhood of an alignment term (no weights): the bumps ``profile``
    over the radius, the ``neighbourhood`` ('radius' or 'nearest') and, for 'nearest',
    ``nearest`` = k."""

    profile: DistanceProfile
    neighbourhood: str = 'radius'
    nearest: int = DEFAULT_NEAREST

    def __post_init__(self):
        if self.neighbourhood not in NEIGHBOURHOODS:
            raise HerdInputError(f'alignment neighbourhood must be one of {NEIGHBOURHOODS}, '
                                 f'got {self.neighbourhood!r}')
        if int(self.nearest) < 1:
            raise HerdInputError(f'alignment nearest must be ≥ 1, got {self.nearest}')

    @staticmethod
    def even(radius: float, size: int = DEFAULT_SIZE, neighbourhood: str = 'radius',
             nearest: int = DEFAULT_NEAREST) -> AlignmentKernel:
        """``size`` bumps evenly over (0, ``radius``)."""
        return AlignmentKernel(DistanceProfile.even(radius, size), neighbourhood, int(nearest))

    @property
    def size(self) -> int:
        """Number of kernel bumps B."""
        return self.profile.size

    def columns(self, positions, velocities, rows) -> np.ndarray:
        """:func:`alignment_columns` with this kernel and neighbourhood."""
        return alignment_columns(positions, velocities, rows, self.profile,
                                 self.neighbourhood, self.nearest)

    def describe(self) -> str:
        """One line: the bumps and the neighbourhood."""
        hood = (f'{self.nearest} nearest within {self.profile.radius:g} m'
                if self.neighbourhood == 'nearest' else
                f'neighbours within {self.profile.radius:g} m')
        return f'{self.size} bumps, {hood}'


@dataclass
class VelocityAlignment:
    """The alignment term of a herd (module docstring): its :class:`AlignmentKernel`, the
    weights ``coef`` (N, B) per agent (in the model's agent order), their standard
    errors ``se`` (N, B) or None, and after a batch fit their covariance ``cov``
    (N, B, B; not kept in the model file)."""

    kernel: AlignmentKernel
    coef: np.ndarray
    se: np.ndarray | None = None
    cov: np.ndarray | None = None

    def __post_init__(self):
        self.coef = np.atleast_2d(np.asarray(self.coef, dtype=float))
        if self.coef.shape[1] != self.kernel.size:
            raise HerdInputError(f'alignment needs {self.kernel.size} weights per agent '
                                 f'(its bumps), got {self.coef.shape[1]}')
        if self.se is not None:
            self.se = np.asarray(self.se, dtype=float).reshape(self.coef.shape)

    def acceleration(self, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """A_i of every agent: positions and velocities (..., N, 2) -> (..., N, 2)."""
        p = np.asarray(positions, dtype=float)
        q = p.reshape((-1,) + p.shape[-2:])
        v = np.broadcast_to(np.asarray(velocities, dtype=float), p.shape).reshape(q.shape)
        n = q.shape[1]
        if len(self.coef) != n:
            raise HerdInputError(f'alignment has weights for {len(self.coef)} agents, the '
                                 f'herd has {n}')
        cols = self.kernel.columns(q, v, np.arange(n))                      # (M, N, B, 2)
        return np.einsum('mnbk,nb->mnk', cols, self.coef).reshape(p.shape)

    def curve(self, distance, agent: int | None = None) -> np.ndarray:
        """K_i(d) of one agent, or of the herd (the mean weights) when ``agent`` is None."""
        w = self.coef.mean(axis=0) if agent is None else self.coef[agent]
        return self.kernel.profile.features(np.asarray(distance, dtype=float)) @ w

    def herd_curve(self, distance) -> tuple[np.ndarray, np.ndarray]:
        """The herd's kernel K̄(d) (the agents' mean) and its standard error (the agents'
        fits are independent; from ``cov`` when known, else from ``se`` alone)."""
        psi = self.kernel.profile.features(np.asarray(distance, dtype=float))
        n = len(self.coef)
        if self.cov is not None:
            var = np.einsum('db,nbc,dc->d', psi, self.cov, psi)
        elif self.se is not None:
            var = (psi ** 2) @ (self.se ** 2).sum(axis=0)
        else:
            var = np.full(psi.shape[0], np.nan)
        return psi @ self.coef.mean(axis=0), np.sqrt(var) / n

    def summary(self, agents) -> dict:
        """Plain types for summary.json: the kernel, the herd's weights with their standard
        errors, each agent's."""
        herd_se = (np.sqrt((self.se ** 2).sum(axis=0)) / len(self.coef)
                   if self.se is not None else np.full(self.kernel.size, np.nan))
        return {'kernel': self.kernel.describe(),
                'bump_centres_m': [float(c) for c in self.kernel.profile.centers],
                'herd_weights': [float(w) for w in self.coef.mean(axis=0)],
                'herd_weights_se': [float(s) for s in herd_se],
                'weights': {a: [float(w) for w in self.coef[i]] for i, a in enumerate(agents)}}

    def to_dict(self, agents) -> dict:
        """The model file's ``alignment`` mapping."""
        k = self.kernel
        body = {'neighbourhood': k.neighbourhood, 'nearest': int(k.nearest),
                'radius': float(k.profile.radius), 'size': int(k.size),
                'weights': {a: [float(x) for x in self.coef[i]] for i, a in enumerate(agents)}}
        if self.se is not None:
            body['weights_se'] = {a: [float(x) for x in self.se[i]]
                                  for i, a in enumerate(agents)}
        return body

    @classmethod
    def from_dict(cls, body: dict, agents, source: str = 'model') -> VelocityAlignment:
        """The term of a model file's ``alignment`` mapping; one clear error otherwise."""
        try:
            kernel = AlignmentKernel.even(float(body['radius']), int(body['size']),
                                          str(body.get('neighbourhood', 'radius')),
                                          int(body.get('nearest', DEFAULT_NEAREST)))
            weights = body['weights']
            coef = np.array([[float(x) for x in weights[a]] for a in agents])
            se = body.get('weights_se')
            se = None if se is None else np.array([[float(x) for x in se[a]] for a in agents])
            return cls(kernel, coef, se)
        except KeyError as exc:
            raise HerdInputError(f'{source}: alignment lacks {exc}') from None
        except (TypeError, ValueError) as exc:
            raise HerdInputError(f'{source}: alignment is malformed ({exc})') from None


def alignment_term(alignment: VelocityAlignment | None, positions, velocities):
    """A_i of every agent, or 0 without an alignment term."""
    if alignment is None:
        return 0.0
    return alignment.acceleration(positions, velocities)
