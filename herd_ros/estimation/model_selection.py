"""Model selection by blocked cross-validation of the one-step prediction error.

The herd model (eq. 2 of Schwager, Anderson & Rus 2007) nests simpler models; on real
animals the full model, fitted on a fixed grid with every pair term, can predict worse than
"the animal stays where it is" (measured on the shipped baboons: 1.41 m one-step RMS
against 0.33 m for stay-put). The candidates, each a set of columns of the regression of
:mod:`herd_ros.model.regressors`:

* ``damping``                     u^{τ+1} = a u^τ + w     (p̂ = p + a (p − p_prev))
* ``damping+field``               + g_i(p), an RBF field on a grid over the visited region
* ``damping+interactions``        + Σ_j f_ij: the paper's pairwise law for up to
  :data:`PAIRWISE_MAX_AGENTS` agents, the shared distance profile of
  :mod:`herd_ros.model.shared_law` for more (2(N − 1) pair parameters per agent are not
  identified from hours of a large herd)
* ``damping+interactions+field``

and, with the shared law, the interaction candidates again with one **distinguished agent**
given its own profile (a dog driving sheep; :mod:`herd_ros.model.shared_law`): unless the
user names them, :func:`screen_for_driver` nominates the agent whose own profile would
explain most of the others' one-step error, and cross-validation keeps it only if it earns
its parameters like any other term; each field at a few resolutions (:func:`field_grids`)
and each with a ridge λ from :data:`RIDGES` (the damping-only model with the smallest only:
a ridge on the damping alone just pulls it towards stay-put) (λ as in
:func:`~herd_ros.estimation.batch_ls.fit_agent`: a penalty λ‖Φ_j‖²θ_j² on every coefficient,
the same as a ridge on standardised columns).

**Blocked cross-validation** (Bergmeir, Hyndman & Koo 2018, for autoregressions; Roberts et
al. 2017, *Ecography* 40:913, for dependent ecological data): every run is cut into
``folds`` contiguous blocks of time; each block is predicted one step ahead by the fit on
all the other blocks. Every candidate is a column subset of one design per field grid, so
each block contributes its sufficient statistics once — G_b = Φ_bᵀΦ_b, c_b = Φ_bᵀY_b,
s_b = Y_bᵀY_b, with Φ = [[A_x, F, 0], [A_y, 0, F]] computed block-wise — and the fit
without block b and its held-out error are small solves:

    θ_−b = (G − G_b + λ D²)⁻¹ (c − c_b),   D² = diag(G − G_b)
    SSE_b = s_b − 2 θ_−bᵀ c_b + θ_−bᵀ G_b θ_−b

(one-step position error = Δt × velocity error). Constant velocity (θ = [1, 0…]) and stay-put
(θ = 0) are scored on the same blocks. A block is **scored** only on its samples inside the
region the other blocks cover (cells of the finest field grid tried where they put the agent
at least ``min_visits`` times): s_b, c_b, G_b of the scoring are those samples' (the fit
without the block still leaves all of it out). A block that leaves the training region
would otherwise judge every candidate on extrapolation — a field where nothing identifies
it — and steer the choice (of a ridge, of the field) by it.

**Choice: the one-standard-error rule** (Hastie, Tibshirani & Friedman, *The Elements of
Statistical Learning*, 2nd ed., §7.10): the simplest candidate (fewest parameters) whose CV
mean squared error exceeds the best's by no more than one standard error of that excess
(paired over the blocks, so the blocks' own difficulty cancels) and by no more than the
best's own standard error over the blocks (HTF's: a candidate that fails badly in one block
has a large paired standard error, and the paired rule alone took one whose CV RMS was 17.3
against the best's 9.9, on a real cattle recording with ridge-less interactions); among
candidates of that size, the lowest CV error (a ridge also shrinks the damping towards
stay-put, so it is not preferred for its own sake). A richer
model must earn its parameters; with no signal in the interactions or the field the damping
model — which the full model nests — is chosen, so a selected fit is not worse than it.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from herd_ros.errors import HerdInputError
# the candidate sets, named here too (model_selection.RIDGES, ...)
from herd_ros.fit_defaults import (DEFAULT_MIN_VISITS, FIELD_CELLS, FOLDS,  # noqa: F401
                                   MEMORIES, PAIRWISE_MAX_AGENTS, RIDGES,
                                   SAMPLES_PER_FIELD_CELL, TERMS)
from herd_ros.model.alignment import AlignmentKernel
from herd_ros.model.rbf_field import FieldGrid, RbfBasis
from herd_ros.model.regressors import AgentRegression, interaction_columns, velocities
from herd_ros.model.shared_law import DEFAULT_PROFILE_SIZE, DistanceProfile, shared_columns
from herd_ros.model.velocity_memory import check_memory, memory_velocities

#: A driver (an agent worth its own profile) is screened for in shared-law herds up to this
#: size (the screen costs O(N²) per sampled step), on up to this many steps.
SCREEN_MAX_AGENTS = 100
SCREEN_STEPS = 4000
#: The least relative drop of the CV mean squared error that keeps the velocity alignment.
ALIGNMENT_MIN_GAIN = 0.01


@dataclass(frozen=True)
class Structure:
    """One candidate: which terms, the field grid (or None), the ridge λ, and the agents
    with their own profile in the shared law's interactions (with its basis ψ')."""

    interactions: bool
    grid: tuple | None          # (nx, ny) or None (no field)
    ridge: float
    own: tuple = ()
    own_profile: DistanceProfile | None = None
    memory: float | tuple = 1.0  # velocity memory κ (1: the paper's u^τ), or one per agent
    alignment: AlignmentKernel | None = None   # velocity alignment (:mod:`alignment`)

    @property
    def terms(self) -> str:
        """The terms as ``damping[+interactions][+alignment][+field]``."""
        return 'damping' + ('+interactions' if self.interactions else '') + \
            ('+alignment' if self.alignment is not None else '') + \
            ('+field' if self.grid is not None else '')

    def label(self) -> str:
        """One line for the selection table: terms, grid, own profiles, memory, alignment,
        ridge."""
        g = f' {self.grid[0]}x{self.grid[1]}' if self.grid is not None else ''
        o = f' own profile {",".join(self.own)}' if self.own else ''
        m = ''
        if isinstance(self.memory, tuple):
            values, counts = np.unique(self.memory, return_counts=True)
            m = ' memory per agent (' + ', '.join(f'{v:g}×{c}' for v, c in
                                                   zip(values[::-1], counts[::-1])) + ')'
        elif self.memory != 1.0:
            m = f' memory {self.memory:g}'
        return f'{self.terms}{g}{o}{m} λ={self.ridge:g}'


@dataclass
class Selection:
    """The candidates' CV scores and the chosen structure."""

    law: str                              # 'pairwise' or 'shared' (for the interactions)
    profile: DistanceProfile | None       # shared law only
    bounds: tuple                         # field bounds (xmin, xmax, ymin, ymax)
    table: list = field(default_factory=list)   # dicts: structure, n_params (mean per agent),
    #                                             rms, mse, excess, excess_se
    baselines: dict = field(default_factory=dict)  # constant_velocity / stay_put CV RMS
    chosen: Structure | None = None
    folds: int = FOLDS
    samples: int = 0
    own_agents: list = field(default_factory=list)      # distinguished agents (shared law)
    own_profile: DistanceProfile | None = None          # their profile ψ'
    outside_region: int = 0     # held-out samples not scored: outside the training region
    radius_choice: dict | None = None   # shared law: the pooled profile's radius by CV

    def as_dict(self) -> dict:
        """Plain types, for the model file and summary.json."""
        c = self.chosen
        return {
            'method': f'blocked cross-validation ({self.folds} blocks per run) of the '
                      f'one-step error, one-standard-error rule',
            'terms': c.terms, 'grid': list(c.grid) if c.grid else [],
            'ridge': float(c.ridge), 'interaction_law': self.law if c.interactions else '',
            'velocity_memory': (list(c.memory) if isinstance(c.memory, tuple)
                                else float(c.memory)),
            'alignment': c.alignment.describe() if c.alignment is not None else '',
            'own_profile_agents': list(self.own_agents) if c.interactions else [],
            'field_bounds': [float(b) for b in self.bounds],
            'held_out_samples': {'scored': int(self.samples),
                                 'outside_training_region': int(self.outside_region)},
            'cv_rms': {'selected': float(self._row(c)['rms']),
                       'constant_velocity': float(self.baselines['constant_velocity']),
                       'stay_put': float(self.baselines['stay_put'])},
            'candidates': [{'structure': r['structure'].label(), 'parameters': r['n_params'],
                            'cv_rms': float(r['rms'])} for r in self.table],
            **({'interaction_radius': self.radius_choice} if self.radius_choice else {}),
        }

    def _row(self, s: Structure) -> dict:
        return next(r for r in self.table if r['structure'] == s)


# -- regression samples ----------------------------------------------------------------
def own_profile_radius(runs_positions, own, floor: float) -> float:
    """r' of the distinguished agents' profile: 1.5 × the 95th percentile of their distance
    to the others (≤ 2000 steps), at least ``floor`` (the shared law's radius). An agent
    that drives the herd acts from wherever it usually is, and the profile's cosine taper
    must not silence it there (at the 95th percentile the taper is still 0.25)."""
    vals = []
    for p in runs_positions:
        q = p[np.unique(np.linspace(0, len(p) - 1, min(len(p), 2000)).astype(int))]
        for k in own:
            d = np.sqrt(((q - q[:, k:k + 1]) ** 2).sum(-1))
            d = np.delete(d, k, axis=1)
            vals.append(d[np.isfinite(d)])
    vals = np.concatenate(vals) if vals else np.zeros(0)
    return float(max(floor, 1.5 * np.percentile(vals, 95) if len(vals) else floor))


def agent_samples(positions: np.ndarray, i: int, dt: float, law: str,
                  profile: DistanceProfile | None, own=(),
                  own_profile: DistanceProfile | None = None, memory: float = 1.0,
                  alignment: AlignmentKernel | None = None, herd_memory=None):
    """The damping/interaction columns of agent i over one run (see :mod:`regressors`).

    Returns (A_x, A_y, y_x, y_y, points) with A = [ū, interaction columns…, alignment
    columns…] (ū the velocity with memory κ = ``memory``, u itself at 1; pairwise: e, −e/d
    per neighbour; shared: the B profile columns, then S·B' of the distinguished agents
    ``own``; with an ``alignment`` kernel its B_a columns of
    :func:`~herd_ros.model.alignment.alignment_columns`, on every agent's ū with
    ``herd_memory`` (default ``memory``)), points = p_i^τ (M, 2) for the field; samples
    need agent i at τ, τ+1, τ+2."""
    p = np.asarray(positions, dtype=float)
    if p.shape[0] < 3:
        return None
    u = velocities(p, dt)
    ubar = memory_velocities(u[:, i:i + 1], memory)[:, 0]
    pt = p[:-2]
    ok = _sample_mask(p, i)
    if not ok.any():
        return None
    if law == 'pairwise':
        e, e_over_d = interaction_columns(pt[ok], i)
        cx = np.column_stack([e[..., 0], -e_over_d[..., 0]])
        cy = np.column_stack([e[..., 1], -e_over_d[..., 1]])
    else:
        inter = shared_columns(pt[ok], i, profile, own, own_profile)[0][:, 0]
        cx, cy = inter[..., 0], inter[..., 1]
    if alignment is not None:
        herd_ubar = memory_velocities(u, memory if herd_memory is None else herd_memory)
        al = alignment.columns(pt[ok], herd_ubar[:-1][ok], [i])[:, 0]     # (M, B_a, 2)
        cx, cy = np.column_stack([cx, al[..., 0]]), np.column_stack([cy, al[..., 1]])
    A_x = np.column_stack([ubar[:-1][ok, 0], cx])
    A_y = np.column_stack([ubar[:-1][ok, 1], cy])
    return A_x, A_y, u[1:][ok, i, 0], u[1:][ok, i, 1], pt[ok, i, :]


def _sample_mask(p: np.ndarray, i: int) -> np.ndarray:
    """Steps τ with agent i at τ, τ+1 and τ+2 (a regression sample): (T−2,) bool."""
    return np.isfinite(p[:-2, i]).all(-1) & np.isfinite(p[1:-1, i]).all(-1) \
        & np.isfinite(p[2:, i]).all(-1)


def _with_memory(stats, A_x, A_y, F, y_x, y_y, ubar):
    """:func:`_stats` with the damping column replaced by ``ubar`` (M, 2), from the stats of
    the same samples: only row/column 0 of G and c[0] change (O(M·p), not O(M·p²))."""
    G, c, s, m = stats[:4]
    ux, uy = ubar[:, 0], ubar[:, 1]
    row = np.concatenate([ux @ A_x + uy @ A_y, F.T @ ux, F.T @ uy])
    row[0] = ux @ ux + uy @ uy
    G = G.copy()
    G[0, :], G[:, 0] = row, row
    c = c.copy()
    c[0] = ux @ y_x + uy @ y_y
    return G, c, s, m


def _stats(A_x, A_y, F, y_x, y_y):
    """G = ΦᵀΦ, c = ΦᵀY, s = YᵀY of Φ = [[A_x, F, 0], [A_y, 0, F]] (never formed)."""
    pa, K = A_x.shape[1], F.shape[1]
    p = pa + 2 * K
    G = np.zeros((p, p))
    G[:pa, :pa] = A_x.T @ A_x + A_y.T @ A_y
    if K:
        FF = F.T @ F
        G[:pa, pa:pa + K] = A_x.T @ F
        G[:pa, pa + K:] = A_y.T @ F
        G[pa:pa + K, :pa] = G[:pa, pa:pa + K].T
        G[pa + K:, :pa] = G[:pa, pa + K:].T
        G[pa:pa + K, pa:pa + K] = FF
        G[pa + K:, pa + K:] = FF
    c = np.concatenate([A_x.T @ y_x + A_y.T @ y_y, F.T @ y_x, F.T @ y_y])
    return G, c, float(y_x @ y_x + y_y @ y_y), len(y_x)


def _solve(G, c, ridge):
    """The ridge solution on standardised columns, the damping (column 0) unpenalised
    (as :func:`~herd_ros.estimation.batch_ls.fit_agent`)."""
    d = np.diag(G).copy()
    scale = np.sqrt(np.where(d > 0, d, 1.0))
    Gs = G / scale[:, None] / scale[None, :]
    cs = c / scale
    if ridge > 0:
        pen = np.full(len(Gs), float(ridge))
        if d[0] > 0:
            pen[0] = 0.0
        Gs = Gs + np.diag(pen)
    theta, *_ = np.linalg.lstsq(Gs, cs, rcond=1e-10)
    return theta / scale


# -- candidates ----------------------------------------------------------------------
#: the shared law's pooled-profile radius is chosen among these multiples of the default
#: (4 × the typical spacing, within [10, 200] m) by cross-validation (:func:`choose_radius`)
RADIUS_FACTORS = (1.0, 2.0, 4.0)
#: a larger radius is kept only if it lowers the CV mean squared error by this share
RADIUS_MIN_GAIN = 0.01


def default_radius(runs_positions) -> float:
    """The shared law's default interaction radius: 4 × :func:`typical_spacing`, within
    [10, 200] m."""
    return float(np.clip(4.0 * typical_spacing(runs_positions), 10.0, 200.0))


def choose_radius(runs_positions, agents, dt, *, folds, bounds, min_visits, own_agents,
                  memory, ridge) -> dict:
    """The pooled profile's radius of the shared law, by blocked cross-validation of the
    damping-and-interactions law (no field; the driver screen as in the selection) at
    :data:`RADIUS_FACTORS` × :func:`default_radius`: the interaction range is part of the
    structure. A tight herd (a flock packed about a dog) makes the default short, and
    cohesion beyond it would be put down to whatever else lies in that direction — the
    dog's profile of a driven flock came out 14 % weak with a 10 m radius against the
    truth's 40 m, 1 % with 30–50 m. The smallest radius within :data:`RADIUS_MIN_GAIN` of
    the best CV error is kept. Returns {'radius', 'tried': {radius: CV RMS (m)}}."""
    base = default_radius(runs_positions)
    radii = sorted({float(np.clip(base * f, 10.0, 200.0)) for f in RADIUS_FACTORS})
    mse = {}
    for r in radii:
        sel = _select_model(runs_positions, agents, dt, folds=folds, ridges=(ridge,), grids=[],
                            terms=['damping+interactions'], bounds=bounds,
                            min_visits=min_visits, law='shared', own_agents=own_agents,
                            memory=memory, memories=(), alignment=None, profile_radius=r)
        mse[r] = min(row['mse'] for row in sel.table if row['structure'].interactions)
    best = min(mse.values())
    radius = min(r for r in radii if mse[r] <= (1.0 + RADIUS_MIN_GAIN) * best)
    return {'radius': radius, 'tried': {float(r): float(dt * np.sqrt(v))
                                        for r, v in mse.items()}}


def typical_spacing(runs_positions) -> float:
    """Median distance (m) of an agent to its nearest neighbour over ≤ 2000 steps."""
    vals = []
    for p in runs_positions:
        q = p[np.unique(np.linspace(0, len(p) - 1, min(len(p), 2000)).astype(int))]
        d = np.sqrt(((q[:, :, None, :] - q[:, None, :, :]) ** 2).sum(-1))
        n = q.shape[1]
        d[:, np.arange(n), np.arange(n)] = np.inf
        nn = np.min(np.where(np.isfinite(d), d, np.inf), axis=2)
        vals.append(nn[np.isfinite(nn)])
    vals = np.concatenate(vals) if vals else np.zeros(0)
    return float(np.median(vals)) if len(vals) else 10.0


def default_alignment(runs_positions) -> AlignmentKernel:
    """The alignment kernel tried by default: :data:`~herd_ros.model.alignment.DEFAULT_SIZE`
    bumps over the shared law's radius (4 × the typical nearest-neighbour spacing, within
    10–200 m), every neighbour within it."""
    from herd_ros.model.alignment import DEFAULT_SIZE
    return AlignmentKernel.even(default_radius(runs_positions), DEFAULT_SIZE)


def field_grids(bounds, samples_per_agent: int, cells=FIELD_CELLS) -> list[tuple]:
    """(nx, ny) for each number of cells in ``cells`` that the data support (at most one
    cell per :data:`SAMPLES_PER_FIELD_CELL` samples), arranged to the region's aspect."""
    w, h = bounds[1] - bounds[0], bounds[3] - bounds[2]
    out = []
    for n in cells:
        if n > samples_per_agent // SAMPLES_PER_FIELD_CELL:
            continue
        nx = int(np.clip(round(np.sqrt(n * w / h)), 1, n))
        ny = int(np.clip(round(n / nx), 1, n))
        if (nx, ny) not in out:
            out.append((nx, ny))
    return out


def screen_for_driver(runs_positions, agents: list[str], dt: float, profile: DistanceProfile,
                      max_steps: int = SCREEN_STEPS):
    """The agent most worth an own profile: for every candidate k, how much of the others'
    one-step error its own profile would remove beyond the damping and the pooled law.

    Per agent i, on up to ``max_steps`` evenly spread steps: the residual r_i of
    u_i^{τ+1} on [u_i^τ, pooled profile columns] and, per k ≠ i, the share of r_i's sum
    of squares explained by k's own-profile columns Z_ik (B' columns ψ'(d_ik) e_ik, radius
    :func:`own_profile_radius` of k) once the base columns are partialled out of them
    (Frisch–Waugh–Lovell). score_k = Σ_{i≠k} that share. Returns (k, score) or None. It only
    nominates: blocked cross-validation then decides whether the own profile is kept."""
    n = len(agents)
    samples = []
    for p in runs_positions:
        T = p.shape[0]
        if T < 3:
            continue
        take = np.unique(np.linspace(0, T - 3, min(T - 2, max_steps)).astype(int))
        samples.append((p[take], p[take + 1], p[take + 2]))
    if not samples:
        return None
    p0 = np.concatenate([s[0] for s in samples])
    p1 = np.concatenate([s[1] for s in samples])
    p2 = np.concatenate([s[2] for s in samples])
    u0, u1 = (p1 - p0) / dt, (p2 - p1) / dt
    bases = [DistanceProfile.even(own_profile_radius(runs_positions, [k], profile.radius),
                                  DEFAULT_PROFILE_SIZE) for k in range(n)]
    score = np.zeros(n)
    for i in range(n):
        ok = np.isfinite(p0[:, i]).all(-1) & np.isfinite(u0[:, i]).all(-1) \
            & np.isfinite(u1[:, i]).all(-1)
        if ok.sum() < 4 * DEFAULT_PROFILE_SIZE:
            continue
        pt = p0[ok]
        pooled = shared_columns(pt, i, profile)[0][:, 0]           # (M, B, 2)
        X = np.vstack([np.column_stack([u0[ok, i, 0], pooled[..., 0]]),
                       np.column_stack([u0[ok, i, 1], pooled[..., 1]])])
        y = np.concatenate([u1[ok, i, 0], u1[ok, i, 1]])
        Q, _ = np.linalg.qr(X)
        r = y - Q @ (Q.T @ y)
        sse = float(r @ r)
        if not sse > 0:
            continue
        for k in range(n):
            if k == i:
                continue
            off = pt[:, k] - pt[:, i]
            d = np.sqrt((off ** 2).sum(-1))
            near = np.isfinite(d) & (d > 0)
            with np.errstate(invalid='ignore', divide='ignore'):
                e = np.where(near[:, None], off / np.where(near, d, 1.0)[:, None], 0.0)
            psi = bases[k].features(np.where(near, d, np.inf))     # (M, B')
            Z = np.vstack([psi * e[:, :1], psi * e[:, 1:]])
            Z = Z - Q @ (Q.T @ Z)
            keep = (Z ** 2).sum(0) > 1e-12 * max(float((Z ** 2).sum()), 1e-300)
            if not keep.any():
                continue
            beta, *_ = np.linalg.lstsq(Z[:, keep], r, rcond=1e-10)
            fitted = Z[:, keep] @ beta
            score[k] += float(fitted @ fitted) / sse
    k = int(np.argmax(score))
    return (k, float(score[k])) if score[k] > 0 else None


def region_cells(where: np.ndarray, region: FieldGrid) -> np.ndarray:
    """Index of the cell of ``region`` holding each point (M,) (points outside the bounds
    fall in the nearest edge cell)."""
    lo_x, hi_x, lo_y, hi_y = region.bounds
    ix = np.clip(((where[:, 0] - lo_x) / (hi_x - lo_x) * region.nx).astype(int), 0,
                 region.nx - 1)
    iy = np.clip(((where[:, 1] - lo_y) / (hi_y - lo_y) * region.ny).astype(int), 0,
                 region.ny - 1)
    return iy * region.nx + ix


def _block_statistics(runs_positions, agents, dt, law, profile, designs, bounds, min_visits,
                      folds, own=(), own_profile=None, progress=None, memory=1.0,
                      memories=None, region=None, alignment=None):
    """Per agent: its field bases per grid and, per design, the sufficient statistics of
    every block (None for a block without samples), for velocity memory ``memory``; with
    ``memories``, a dict {κ: that list} for each κ of them instead (the samples are formed
    once, only the damping column changes: :func:`_with_memory`).

    A block's statistics are (G, c, s, m) of all its samples (what the fits without it
    leave out) followed by (G, c, s, m) of those it is **scored** on: with ``region`` (a
    :class:`FieldGrid`), only the samples in cells where the *other* blocks put the agent
    at least ``min_visits`` times — a held-out block that leaves the training region would
    judge every candidate on extrapolation (a field where no data identify it), not on how
    the herd moves."""
    kappas = [memory] if memories is None else list(memories)
    out = {k: [] for k in kappas}
    for i, a in enumerate(agents):
        bases = {}
        for g in designs:
            if g is None:
                continue
            grid = FieldGrid(g[0], g[1], tuple(bounds))
            visited = np.concatenate([p[:-2, i] for p in runs_positions if len(p) >= 3])
            visited = visited[np.isfinite(visited).all(-1)]
            bases[g] = RbfBasis.from_grid(grid, visited, min_visits)
        entries = []       # per block: (samples, memory velocities) or None
        for p in runs_positions:
            T = p.shape[0]
            if T < 3:
                continue
            edges = np.linspace(0, T - 2, min(folds, T - 2) + 1).astype(int)
            for b0, b1 in zip(edges[:-1], edges[1:]):
                q = p[b0:b1 + 2]
                smp = agent_samples(q, i, dt, law, profile, own, own_profile, memory,
                                    alignment)
                ubars = None
                if smp is not None and memories is not None:
                    u = velocities(q[:, i:i + 1], dt)
                    ok = _sample_mask(q, i)
                    ubars = {k: memory_velocities(u, k)[:-1, 0][ok] for k in kappas}
                entries.append(None if smp is None else (smp, ubars))
        outside = _outside_training_region(entries, region, min_visits)
        blocks = {k: {g: [] for g in designs} for k in kappas}
        for e, out_b in zip(entries, outside):
            for g in designs:
                if e is None:
                    for k in kappas:
                        blocks[k][g].append(None)
                    continue
                (A_x, A_y, y_x, y_y, where), ubars = e
                F = bases[g].features(where) if g is not None else np.zeros((len(y_x), 0))
                for k in kappas:
                    def stats_of(mask=None):
                        sub = (slice(None) if mask is None else mask)
                        st = _stats(A_x[sub], A_y[sub], F[sub], y_x[sub], y_y[sub])
                        if memories is None:
                            return st
                        return _with_memory(st, A_x[sub], A_y[sub], F[sub], y_x[sub],
                                            y_y[sub], ubars[k][sub])
                    full = stats_of()
                    if not out_b.any():
                        scored = full
                    else:
                        gone = stats_of(out_b)
                        scored = (full[0] - gone[0], full[1] - gone[1], full[2] - gone[2],
                                  full[3] - gone[3])
                    blocks[k][g].append(full + scored)
        for k in kappas:
            out[k].append((bases, blocks[k]))
        if progress is not None:
            progress(a)
    return out[memory] if memories is None else out


def _outside_training_region(entries, region, min_visits) -> list:
    """Per block: which of its samples lie in cells of ``region`` that the other blocks
    visited fewer than ``min_visits`` times (all False without a region)."""
    if region is None:
        return [np.zeros(0 if e is None else len(e[0][2]), bool) for e in entries]
    cells = [None if e is None else region_cells(e[0][4], region) for e in entries]
    size = region.nx * region.ny
    counts = [np.zeros(size) if c is None else np.bincount(c, minlength=size) for c in cells]
    total = sum(counts)
    return [np.zeros(0, bool) if c is None else (total - n)[c] < min_visits
            for c, n in zip(cells, counts)]


def select_model(runs_positions: list[np.ndarray], agents: list[str], dt: float, *,
                 profile_radius: float | None = None, **options) -> Selection:
    """Score every candidate by blocked CV and choose one (module docstring; the options are
    :func:`_select_model`'s). With the shared law and no ``profile_radius``: the selection
    at :func:`default_radius`, and, when it keeps the interactions, their radius chosen by
    :func:`choose_radius` (the selection made again at that radius if it differs); the
    choice is in ``Selection.radius_choice``."""
    if profile_radius is not None:
        return _select_model(runs_positions, agents, dt, profile_radius=profile_radius,
                             **options)
    sel = _select_model(runs_positions, agents, dt, **options)
    if sel.law != 'shared' or not sel.chosen.interactions:
        return sel
    choice = choose_radius(runs_positions, agents, dt, folds=options.get('folds', FOLDS),
                           bounds=sel.bounds, min_visits=options.get('min_visits',
                                                                     DEFAULT_MIN_VISITS),
                           own_agents=options.get('own_agents'),
                           memory=options.get('memory', 1.0),
                           ridge=float(min(options.get('ridges', RIDGES))))
    if not np.isclose(choice['radius'], sel.profile.radius):
        sel = _select_model(runs_positions, agents, dt, profile_radius=choice['radius'],
                            **options)
    sel.radius_choice = choice
    return sel


def _select_model(runs_positions: list[np.ndarray], agents: list[str], dt: float, *,
                  folds: int = FOLDS, ridges=RIDGES, grids=None, terms=None,
                  bounds=None, min_visits: int = DEFAULT_MIN_VISITS, law: str | None = None,
                  own_agents=None, progress=None, memory: float = 1.0,
                  memories=MEMORIES, alignment='auto', alignment_required: bool = False,
                  profile_radius: float | None = None) -> Selection:
    """Score every candidate by blocked CV and choose one (see the module docstring).

    Args:
        runs_positions: (T, N, 2) arrays on one clock, columns in ``agents`` order.
        grids: field grids to try (default :func:`field_grids`); ``[]`` = no field.
        terms: restrict to these of :data:`TERMS` (default all).
        ridges: ridge values to try.
        bounds: field bounds (default: the bounding box of the finite positions).
        law: 'pairwise' or 'shared' for the interactions (default by herd size; 'shared'
            when there are ``own_agents``).
        own_agents: distinguished agents with their own profile in every candidate with
            interactions (shared law; module docstring of :mod:`herd_ros.model.shared_law`).
            None (default): with the shared law and up to :data:`SCREEN_MAX_AGENTS` agents,
            :func:`screen_for_driver` nominates one agent and its candidates with an own
            profile are cross-validated beside the others; ``[]``: none.
        memory: the velocity memory κ of every candidate (:mod:`velocity_memory`; 1 = the
            paper's model).
        memories: other κ tried on the structure the one-standard-error rule chooses
            among the candidates above (a last pass; ``()`` = none). κ counts as one
            parameter of the herd, so a memory is kept only if it earns it.
        alignment: the velocity alignment tried on the chosen structure, with and without
            the position interactions (:mod:`herd_ros.model.alignment`; a pass before the
            memory's): an :class:`~herd_ros.model.alignment.AlignmentKernel`, 'auto' (the
            kernel :func:`default_alignment` makes from the data, unless ``terms`` pins the
            terms), or None (not tried).
            Kept only if it earns its parameters under the same rule and lowers the CV mean
            squared error by at least :data:`ALIGNMENT_MIN_GAIN` (1 %).
        alignment_required: choose among the alignment candidates only (``herd-ros fit
            --alignment on``): the others stay in the table, scored, not eligible.
        profile_radius: the shared law's interaction radius (m); None:
            :func:`default_radius`.
    """
    memory = check_memory(memory)
    memories = [check_memory(k) for k in memories if float(k) != memory]
    n = len(agents)
    if n < 2:
        raise HerdInputError('model selection needs at least two agents')
    pts = np.concatenate([p.reshape(-1, 2) for p in runs_positions])
    pts = pts[np.isfinite(pts).all(-1)]
    if len(pts) < 3:
        raise HerdInputError('no finite positions to select a model on')
    if bounds is None:
        bounds = FieldGrid.over(pts, 1, 1).bounds
    given = list(own_agents or [])
    own = check_own_agents(given, agents)
    if own and law == 'pairwise':
        raise HerdInputError('own profiles belong to the shared law (the pairwise law already '
                             'gives every pair its own parameters): drop --law pairwise')
    law = law or ('pairwise' if n <= PAIRWISE_MAX_AGENTS and not own else 'shared')
    profile = own_profile = None
    if law == 'shared':
        radius = default_radius(runs_positions) if profile_radius is None else profile_radius
        profile = DistanceProfile.even(float(radius), DEFAULT_PROFILE_SIZE)
        if own:
            own_profile = DistanceProfile.even(
                own_profile_radius(runs_positions, own, radius), DEFAULT_PROFILE_SIZE)
    steps = sum(max(p.shape[0] - 2, 0) for p in runs_positions)
    if grids is None:
        grids = field_grids(bounds, steps)
    grids = [tuple(g) for g in grids]
    all_terms = terms is None
    terms = list(TERMS if terms is None else terms)
    bad = [t for t in terms if t not in TERMS]
    if bad:
        raise HerdInputError(f'unknown terms {bad}; choose from {", ".join(TERMS)}')
    want_field = any('field' in t for t in terms)
    field_grid_list = grids if want_field else []
    designs = [None] + field_grid_list           # None: no field columns
    # held-out samples are scored only inside the region the other blocks cover, on the
    # finest field grid tried (the field that would extrapolate furthest)
    region = (FieldGrid(*max(field_grid_list, key=lambda g: g[0] * g[1]), tuple(bounds))
              if field_grid_list else None)
    def candidates_of(names, prof, pass_terms, pass_grids):
        out = []
        for t in pass_terms:
            inter = 'interactions' in t
            for g in (pass_grids if 'field' in t else [None]):
                # a ridge on the damping alone only pulls it towards stay-put (scored anyway)
                for lam in (ridges if t != 'damping' else sorted(ridges)[:1]):
                    out.append(Structure(inter, g, float(lam), names if inter else (),
                                         prof if inter and names else None, memory))
        return out

    def score(per_agent, group, pass_designs, by_agent=None, n_align=0):
        """Add every candidate's held-out SSE per block (and its parameter count); with
        ``by_agent`` (a dict), also each agent's, (N, blocks) per candidate. ``n_align``:
        the statistics' last alignment columns (before the field)."""
        for i, (bases, blocks) in enumerate(per_agent):
            for g in pass_designs:
                stats = blocks[g]
                live = [k for k, st in enumerate(stats) if st is not None]
                if not live:
                    continue
                G_tot = sum(stats[k][0] for k in live)
                c_tot = sum(stats[k][1] for k in live)
                K = bases[g].size if g is not None else 0
                pa = stats[live[0]][0].shape[0] - 2 * K
                for s in group:
                    if s.grid != g:
                        continue
                    cols = np.r_[0, (np.arange(1, pa - n_align) if s.interactions else []),
                                 (np.arange(pa - n_align, pa) if s.alignment is not None
                                  else []),
                                 (np.arange(pa, pa + 2 * K) if g is not None else [])
                                 ].astype(int)
                    n_params[s] = n_params.get(s, 0) + len(cols) / n
                    for k in live:
                        G_b, c_b = stats[k][:2]            # all of the block: left out
                        Gs, cs, ss = stats[k][4:7]         # its samples scored
                        Gt = (G_tot - G_b)[np.ix_(cols, cols)]
                        ct = (c_tot - c_b)[cols]
                        theta = _solve(Gt, ct, s.ridge)
                        e = max(ss - 2 * theta @ cs[cols]
                                + theta @ Gs[np.ix_(cols, cols)] @ theta, 0.0)
                        sse[s][k] += e
                        if by_agent is not None:
                            by_agent.setdefault(s, np.zeros((n, n_blocks)))[i, k] += e

    # first pass: every term, with the given own profiles (or none)
    names0 = tuple(agents[k] for k in own)
    candidates = candidates_of(names0, own_profile, terms, field_grid_list)
    if not candidates:
        raise HerdInputError('no candidate model to select from (check --terms/--grid)')
    # the baselines need the plain velocity u in the damping column (not ū of a forced κ)
    if memory == 1.0:
        base_stats = plain_stats = _block_statistics(
            runs_positions, agents, dt, law, profile, designs, bounds, min_visits, folds, own,
            own_profile, progress=progress, region=region)
    else:
        both = _block_statistics(runs_positions, agents, dt, law, profile, designs, bounds,
                                 min_visits, folds, own, own_profile, progress=progress,
                                 memories=[1.0, memory], region=region)
        base_stats, plain_stats = both[memory], both[1.0]
    n_blocks = len(base_stats[0][1][None])
    # per block: SSE (summed over agents) and sample count, per candidate and baselines
    sse = {s: np.zeros(n_blocks) for s in candidates}
    base = {'constant_velocity': np.zeros(n_blocks), 'stay_put': np.zeros(n_blocks)}
    count = np.zeros(n_blocks)
    outside = np.zeros(n_blocks)       # held-out samples outside the training region
    n_params = {}
    for bases, blocks in plain_stats:
        for k, st in enumerate(blocks[None]):
            if st is not None:
                G_b, c_b, s_b, m_b = st[4:]           # the samples scored
                outside[k] += st[3] - m_b
                base['stay_put'][k] += s_b
                base['constant_velocity'][k] += s_b - 2 * c_b[0] + G_b[0, 0]
                count[k] += m_b
    score(base_stats, candidates, designs)
    # second pass (shared law, no agents named): a nominated driver's own profile in the
    # interaction terms, on the no-field design and the first pass's best interaction grid
    inter_terms = [t for t in terms if 'interactions' in t]
    if (own_agents is None and law == 'shared' and inter_terms
            and n <= SCREEN_MAX_AGENTS and count.sum() > 0):
        nominee = screen_for_driver(runs_positions, agents, dt, profile)
        if nominee is not None:
            k = nominee[0]
            prof = DistanceProfile.even(own_profile_radius(runs_positions, [k], profile.radius),
                                        DEFAULT_PROFILE_SIZE)
            best_inter = min((s for s in candidates if s.interactions),
                             key=lambda s: sse[s].sum())
            grids2 = [best_inter.grid] if best_inter.grid is not None else []
            group = candidates_of((agents[k],), prof, inter_terms, grids2)
            for s in group:
                sse[s] = np.zeros(n_blocks)
            stats2 = _block_statistics(runs_positions, agents, dt, law, profile,
                                       [None] + grids2, bounds, min_visits, folds, [k], prof,
                                       progress=progress, memory=memory, region=region)
            score(stats2, group, [None] + grids2)
            candidates += group
    used = count > 0
    if not used.any():
        raise HerdInputError('no block has the three consecutive steps a sample needs')
    table, chosen = _one_standard_error(candidates, sse, n_params, count, dt)
    excluded = set()            # scored, shown, not eligible (an alignment that gains too little)
    if isinstance(alignment, str):     # 'auto': tried unless the terms were pinned
        alignment = (default_alignment(runs_positions) if alignment == 'auto' and all_terms
                     else None)
    if alignment is not None:
        # the alignment of the chosen structure, with and without the position interactions
        own_k = [agents.index(a) for a in chosen.own]
        design = [chosen.grid]
        group = [replace(chosen, alignment=alignment)]
        if inter_terms and chosen.interactions:
            group.append(replace(chosen, interactions=False, own=(), own_profile=None,
                                 alignment=alignment))
        elif inter_terms:
            group.append(replace(chosen, interactions=True, alignment=alignment))
        stats_a = _block_statistics(runs_positions, agents, dt, law, profile, design, bounds,
                                    min_visits, folds, own_k, chosen.own_profile,
                                    progress=progress, memory=memory, region=region,
                                    alignment=alignment)
        for s in group:
            sse[s] = np.zeros(n_blocks)
            n_params.pop(s, None)
        score(stats_a, group, design, n_align=alignment.size)
        before = sse[chosen].sum()
        candidates += group
        # kept only if it also matters: the held-out MSE ALIGNMENT_MIN_GAIN below the
        # structure it was tried on (a herd without alignment can still show a significant
        # but negligible gain where its other terms are misspecified); tried ones stay in
        # the table either way
        if alignment_required:
            excluded.update(c for c in candidates if c.alignment is None)
        elif min(sse[s].sum() for s in group) > (1 - ALIGNMENT_MIN_GAIN) * before:
            excluded.update(group)
        table, chosen = _one_standard_error(candidates, sse, n_params, count, dt, excluded)
    # last pass: the velocity memory of the chosen structure (one parameter of the herd)
    if memories:
        own_k = [agents.index(a) for a in chosen.own]
        design = [chosen.grid]
        kappas = [memory] + memories
        stats3 = _block_statistics(runs_positions, agents, dt, law, profile, design, bounds,
                                   min_visits, folds, own_k, chosen.own_profile,
                                   progress=progress, memory=memory, memories=kappas,
                                   region=region, alignment=chosen.alignment)
        by_agent = {}
        variants = []
        for kappa in kappas:
            # the κ = memory variant is ``chosen`` itself: scored again for its per-agent
            # errors (the same SSE and parameter count as in its own pass)
            s_k = replace(chosen, memory=kappa)
            sse[s_k] = np.zeros(n_blocks)
            n_params.pop(s_k, None)
            score(stats3[kappa], [s_k], design, by_agent,
                  n_align=chosen.alignment.size if chosen.alignment is not None else 0)
            variants.append(s_k)
            if kappa != memory:
                n_params[s_k] += 1.0 / n
                candidates.append(s_k)
        # and one κ per agent: each agent's own best by its CV error (one parameter each)
        own_err = np.stack([by_agent[v].sum(1) for v in variants])       # (κ, N)
        pick = np.argmin(own_err, axis=0)
        if len(set(pick)) > 1:
            s_pa = replace(chosen, memory=tuple(float(kappas[j]) for j in pick))
            sse[s_pa] = sum(by_agent[variants[j]][i] for i, j in enumerate(pick))
            n_params[s_pa] = n_params[chosen] + 1.0
            candidates.append(s_pa)
        table, chosen = _one_standard_error(candidates, sse, n_params, count, dt, excluded)
    total = count[used].sum()
    sel = Selection(law=law, profile=profile, bounds=tuple(float(b) for b in bounds),
                    table=table, folds=folds, samples=int(total),
                    outside_region=int(outside.sum()),
                    baselines={m: dt * float(np.sqrt(v[used].sum() / total))
                               for m, v in base.items()},
                    own_agents=list(chosen.own), own_profile=chosen.own_profile)
    sel.chosen = chosen
    return sel


def _one_standard_error(candidates, sse, n_params, count, dt, excluded=frozenset()):
    """The table of candidates (CV RMS, MSE, excess over the best and its standard error,
    paired over the blocks) and the structure the one-standard-error rule chooses among
    those not ``excluded`` (the best of them is the reference)."""
    used = count > 0
    total = count[used].sum()
    table = []
    mse_blocks = {}
    for s in candidates:
        mse_blocks[s] = sse[s][used] / count[used]
        table.append({'structure': s, 'n_params': round(n_params.get(s, 0), 2),
                      'rms': dt * np.sqrt(sse[s][used].sum() / total),
                      'mse': sse[s][used].sum() / total})
    best = min((r for r in table if r['structure'] not in excluded), key=lambda r: r['mse'])
    nb = int(used.sum())
    # the best's own standard error over the blocks (HTF's): a candidate whose mean excess
    # is beyond it is worse, however erratic its blocks are
    best_se = float(np.std(mse_blocks[best['structure']], ddof=1) / np.sqrt(nb)) \
        if nb > 1 else 0.0
    for r in table:
        # paired over the blocks: the blocks' own difficulty cancels
        diff = mse_blocks[r['structure']] - mse_blocks[best['structure']]
        r['excess'] = float(r['mse'] - best['mse'])
        r['excess_se'] = float(np.std(diff, ddof=1) / np.sqrt(nb)) if nb > 1 else 0.0
    eligible = [r for r in table if r['excess'] <= min(r['excess_se'], best_se)
                and r['structure'] not in excluded]
    return table, min(eligible, key=lambda r: (r['n_params'], r['mse']))['structure']


def check_own_agents(own_agents, agents) -> list[int]:
    """Indices of the distinguished agents; one clear error for names not in the herd."""
    unknown = [a for a in own_agents if a not in agents]
    if unknown:
        raise HerdInputError(f'own-profile agent(s) {", ".join(unknown)} not in the data '
                             f'(agents: {", ".join(agents)})')
    if len(set(own_agents)) != len(own_agents):
        raise HerdInputError('an own-profile agent is listed twice')
    return [agents.index(a) for a in own_agents]


def structured_regression(runs_positions, i: int, agents: list[str], dt: float,
                          structure: Structure, law: str, profile, basis: RbfBasis | None,
                          own=(), own_profile=None) -> AgentRegression:
    """The regression of agent i for ``structure`` over whole runs (for the final fit by
    :func:`~herd_ros.estimation.batch_ls.fit_agent`). A distinguished agent's block with
    itself (zero columns) is left out: ``fit_structure`` puts zeros back."""
    memory = structure.memory[i] if isinstance(structure.memory, tuple) else structure.memory
    herd_memory = (np.asarray(structure.memory, dtype=float)
                   if isinstance(structure.memory, tuple) else structure.memory)
    parts = [agent_samples(p, i, dt, law, profile, own, own_profile, memory,
                           structure.alignment, herd_memory) for p in runs_positions]
    parts = [s for s in parts if s is not None]
    if not parts:
        raise HerdInputError(f'agent {agents[i]}: no three consecutive steps to fit on')
    A_x = np.vstack([s[0] for s in parts])
    A_y = np.vstack([s[1] for s in parts])
    n_align = structure.alignment.size if structure.alignment is not None else 0
    if not structure.interactions:
        keep = np.r_[0, A_x.shape[1] - n_align:A_x.shape[1]].astype(int)
        A_x, A_y = A_x[:, keep], A_y[:, keep]
    elif i in own:
        B, Bo = profile.size, own_profile.size
        s0 = 1 + B + list(own).index(i) * Bo
        keep = np.r_[0:s0, s0 + Bo:A_x.shape[1]]
        A_x, A_y = A_x[:, keep], A_y[:, keep]
    pts = np.vstack([s[4] for s in parts])
    F = basis.features(pts) if (structure.grid is not None and basis is not None) \
        else np.zeros((len(pts), 0))
    neighbors = [agents[j] for j in range(len(agents)) if j != i]
    return AgentRegression(agents[i], neighbors, A_x, A_y, F,
                           np.concatenate([s[2] for s in parts]),
                           np.concatenate([s[3] for s in parts]))
