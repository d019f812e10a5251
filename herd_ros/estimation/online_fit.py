"""Online identification of the herd model: snapshots in, RLS of every agent, model out.

:class:`OnlineHerdEstimator` is the functional core of the ``estimator`` node and of
``herd-ros fit --online``. It takes herd snapshots p^τ (N, 2) one at a time on the herd
clock, and for every three consecutive snapshots τ, τ+1, τ+2 one step Δt apart it updates
every agent's θ_i with the regression of eq. 8 (Schwager et al. 2007),

    u_i^{τ+1} = H_i(p^τ, p^{τ+1}) θ_i + w_i^τ,   u^τ = (p^{τ+1} − p^τ)/Δt,

by the batched rank-2 RLS of :mod:`herd_ros.estimation.rls` (the x and y rows of a step
together). Two laws (``law``):

- ``pairwise`` — the paper's law, the same rows as the batch fit
  (:mod:`herd_ros.model.regressors`): θ_i = [a_i, θ1_i·, θ2_i·, θu_i·, θv_i·];
  p = 1 + 2(N − 1) + 2K. Every row needs every neighbour, so a snapshot with any agent
  missing updates nobody.
- ``shared`` — :mod:`herd_ros.model.shared_law`: θ_i = [a_i, c_i1..c_iB, θu_i·, θv_i·],
  p = 1 + B + 2K whatever N. An agent is skipped when it is missing or when an absent animal
  was last seen within the interaction radius of it (its row would lack that neighbour).

**Field centres online.** The estimator cannot prune centres before it has seen the data,
so it estimates the coefficients of *every* centre of the fixed grid (``field_grid`` ×
``field_bounds``); centres the herd never visits are unexcited directions, which the
directional forgetting of the RLS leaves at their prior (θ₀ = 0, covariance p₀) instead of
winding up. Pruning is **lazy**: the model file keeps, per agent, only the centres whose
cell that agent visited at least ``min_visits`` times (the batch fit's rule), so exported
fields stay bounded away from the data; the kept coefficients are re-solved with the dropped
ones fixed at zero (:meth:`OnlineHerdEstimator.pruned_estimate`), which is exactly the
least-squares fit on the pruned basis.

**Gaps.** A snapshot whose step from the previous one is not Δt (relative tolerance 10⁻³)
starts a new chain (no update across it); a snapshot not later than the previous one is
ignored. NaN positions mark an agent missing or stale in that snapshot.

**Diagnostics** per agent: samples, RMS of the a-priori (innovation) residual and its
lag-1 autocorrelation r₁ (white if |r₁| < 1.96/√n, Box & Jenkins), over a window of
about ``stats_window`` samples (exponential weighting), and the condition number of P_i.

**Ranges**: the running mean and covariance of each agent's positions and of its offset
from the others' centroid are its home range and its place in the herd; with the gain of
the Ornstein-Uhlenbeck home range ((S2) of :mod:`herd_ros.model.space_use_field`) they
are the pulls at those ranges' edges that keep a law run freely — the robots — in its
animal's range and place (:meth:`OnlineHerdEstimator.home_pull`,
:meth:`OnlineHerdEstimator.herd_place`; published with θ and saved in the model).

**Checkpoints**: :meth:`OnlineHerdEstimator.save_checkpoint` writes every array of the
state into one ``.npz`` by write-then-rename (``os.replace``), so a kill at any moment leaves
either the previous or the new checkpoint, never half a file.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.estimation.rls import HerdRLS
from herd_ros.model.herd_model import AgentLaw, HerdModel
from herd_ros.model.herd_place import place_coupling, place_offsets
from herd_ros.model.model_file import atomic_open
from herd_ros.model.rbf_field import DEFAULT_MIN_VISITS, FieldGrid, RbfBasis
from herd_ros.model.regressors import pairwise_columns
from herd_ros.model.shared_law import (DistanceProfile, SharedLawModel,
                                       shared_rows)
from herd_ros.model.space_use_field import range_gain

LAWS = ('pairwise', 'shared')
#: positions an agent needs before its home pull (:meth:`OnlineHerdEstimator.home_pull`) acts
MIN_HOME_POSITIONS = 10
STEP_TOLERANCE = 1e-3


# -- the regression of each law, vectorised over agents --------------------------------------
class PairwiseRegressor:
    """Rows of the paper's pairwise law for all agents of one step (as :mod:`regressors`)."""

    law = 'pairwise'

    def __init__(self, agents: list[str], basis: RbfBasis):
        if len(agents) < 2:
            raise HerdInputError(f'the pairwise law needs at least two agents, got {agents}')
        self.agents, self.basis = list(agents), basis
        n = len(agents)
        self.n_params = 1 + 2 * (n - 1) + 2 * basis.size
        self.field_offset = 2 * n - 1                 # index of field_u[0] in θ_i

    def neighbors(self, i: int) -> list[str]:
        """The neighbours of agent ``i`` in the order of its θ1/θ2 entries."""
        return [a for k, a in enumerate(self.agents) if k != i]

    def labels(self) -> list[str]:
        """The names of θ_i's entries (pairwise law), in order."""
        n, K = len(self.agents), self.basis.size
        return (['damping'] + [f'theta1_{k}' for k in range(1, n)]
                + [f'theta2_{k}' for k in range(1, n)]
                + [f'field_u_{k}' for k in range(K)] + [f'field_v_{k}' for k in range(K)])

    def rows(self, p_prev: np.ndarray, p_cur: np.ndarray, dt: float):
        """H (N, 2, p) and valid (N,) for the target u^{τ+1}, from p^τ and p^{τ+1}."""
        p0 = np.asarray(p_prev, dtype=float)
        n, K = p0.shape[0], self.basis.size
        u = (np.asarray(p_cur, dtype=float) - p0) / dt
        e, e_over_d, coincident = pairwise_columns(p0[None], np.arange(n))
        e, e_over_d = e[0], e_over_d[0]                        # (N, N−1, 2)
        H = np.zeros((n, 2, self.n_params))
        H[:, :, 0] = u
        H[:, :, 1:n] = np.swapaxes(e, 1, 2)
        H[:, :, n:2 * n - 1] = -np.swapaxes(e_over_d, 1, 2)
        phi = self.basis.features(np.nan_to_num(p0))
        H[:, 0, 2 * n - 1:2 * n - 1 + K] = phi
        H[:, 1, 2 * n - 1 + K:] = phi
        valid = (np.isfinite(p0).all(axis=1) & np.isfinite(u).all(axis=1)
                 & ~coincident[0])
        return H, valid

    def missing_neighbors(self, missing: np.ndarray, last_seen: np.ndarray, p_prev):
        """Missing neighbours drop out of the sum (:meth:`rows`): no row is excluded."""
        return np.zeros(len(self.agents), dtype=bool)

    def to_model(self, theta, theta_se, noise_cov, bases, dt, frame_id='map', datum=None):
        """The pairwise :class:`HerdModel` of the estimate θ (agent × param), its standard
        errors and Q."""
        n, K = len(self.agents), self.basis.size
        laws = {}
        for i, a in enumerate(self.agents):
            th, keep = theta[i], bases[i]
            fu, fv = th[2 * n - 1:2 * n - 1 + K][keep], th[2 * n - 1 + K:][keep]
            se = theta_se[i]
            se = np.concatenate([se[:2 * n - 1], se[2 * n - 1:2 * n - 1 + K][keep],
                                 se[2 * n - 1 + K:][keep]])
            basis = RbfBasis(self.basis.centers[keep], self.basis.sigma[keep])
            laws[a] = AgentLaw(damping=float(th[0]), neighbors=self.neighbors(i),
                               theta1=th[1:n], theta2=th[n:2 * n - 1], basis=basis,
                               field_u=fu, field_v=fv, noise_cov=noise_cov[i], theta_se=se)
        return HerdModel(agents=list(self.agents), dt=dt, laws=laws, frame_id=frame_id,
                         datum=datum)


class SharedRegressor:
    """Rows of the shared law (:mod:`herd_ros.model.shared_law`) for all agents of one step."""

    law = 'shared'

    def __init__(self, agents: list[str], basis: RbfBasis, profile: DistanceProfile):
        self.agents, self.basis, self.profile = list(agents), basis, profile
        self.n_params = 1 + profile.size + 2 * basis.size
        self.field_offset = 1 + profile.size

    def labels(self) -> list[str]:
        """The names of θ_i's entries (shared law), in order."""
        K = self.basis.size
        return (['damping'] + [f'profile_{b}' for b in range(self.profile.size)]
                + [f'field_u_{k}' for k in range(K)] + [f'field_v_{k}' for k in range(K)])

    def rows(self, p_prev, p_cur, dt):
        """The regression rows of one snapshot pair, and which agents have one."""
        return shared_rows(p_prev, p_cur, dt, self.profile, self.basis)

    def missing_neighbors(self, missing: np.ndarray, last_seen: np.ndarray, p_prev):
        """Missing neighbours drop out of the sum (doc/formats.md, ``predict``): no row is
        excluded."""
        return np.zeros(len(self.agents), dtype=bool)

    def to_model(self, theta, theta_se, noise_cov, bases, dt, frame_id='map', datum=None):
        """The :class:`SharedLawModel` of the estimate θ (agent × param), its standard errors
        and Q."""
        B, K = self.profile.size, self.basis.size
        fu, fv, bs, se = [], [], [], []
        for i in range(len(self.agents)):
            keep = bases[i]
            fu.append(theta[i, 1 + B:1 + B + K][keep])
            fv.append(theta[i, 1 + B + K:][keep])
            bs.append(RbfBasis(self.basis.centers[keep], self.basis.sigma[keep]))
            s = theta_se[i]
            se.append(np.concatenate([s[:1 + B], s[1 + B:1 + B + K][keep], s[1 + B + K:][keep]]))
        return SharedLawModel(agents=list(self.agents), dt=dt, profile=self.profile,
                              damping=theta[:, 0], profile_coef=theta[:, 1:1 + B], bases=bs,
                              field_u=fu, field_v=fv, noise_cov=noise_cov, theta_se=se,
                              frame_id=frame_id, datum=datum)


class AlignedRegressor:
    """A law's regressor with the velocity alignment's columns appended
    (:mod:`herd_ros.model.alignment`): θ_i = [the law's θ_i, w_i1 … w_iB]."""

    def __init__(self, base, kernel):
        self.base, self.kernel = base, kernel
        self.law, self.agents, self.basis = base.law, base.agents, base.basis
        self.n_params = base.n_params + kernel.size
        self.field_offset = base.field_offset

    def __getattr__(self, name):            # neighbors, profile: the law's
        return getattr(self.base, name)

    def labels(self) -> list[str]:
        """The base law's names of θ_i's entries, then the alignment weights'."""
        return self.base.labels() + [f'alignment_{b}' for b in range(self.kernel.size)]

    def rows(self, p_prev, p_cur, dt):
        """The base law's regression rows of one snapshot pair with the alignment columns added."""
        H, valid = self.base.rows(p_prev, p_cur, dt)
        p0 = np.asarray(p_prev, dtype=float)
        u = (np.asarray(p_cur, dtype=float) - p0) / dt
        A = self.kernel.columns(p0[None], u[None], np.arange(len(p0)))[0]   # (N, B, 2)
        return np.concatenate([H, np.swapaxes(A, 1, 2)], axis=2), valid

    def missing_neighbors(self, missing, last_seen, p_prev):
        """As the base law's."""
        return self.base.missing_neighbors(missing, last_seen, p_prev)

    def to_model(self, theta, theta_se, noise_cov, bases, dt, frame_id='map', datum=None):
        """The base law's model of θ with the alignment weights of θ's last columns."""
        from herd_ros.model.alignment import VelocityAlignment
        B = self.kernel.size
        theta, theta_se = np.asarray(theta), np.asarray(theta_se)
        model = self.base.to_model(theta[:, :-B], theta_se[:, :-B], noise_cov, bases, dt,
                                   frame_id, datum)
        model.alignment = VelocityAlignment(self.kernel, theta[:, -B:], theta_se[:, -B:])
        return model


@dataclass
class SnapshotResult:
    """What one snapshot did: ``status`` is 'updated', 'primed', 'gap', 'between' (less
    than a model step after the last snapshot used: a herd clock finer than the model's
    step, skipped) or 'backwards'."""

    status: str
    updated: np.ndarray | None = None      # (N,) bool
    residual: np.ndarray | None = None     # (N, 2) a-priori residual (NaN where skipped)
    step: float | None = None


class OnlineHerdEstimator:
    """Streaming identification of a herd (module docstring). Plain arrays, no ROS."""

    def __init__(self, agents, dt: float, law: str = 'pairwise', field_grid=(6, 6),
                 field_bounds=(-75.0, 75.0, -75.0, 75.0), forgetting: float = 1.0,
                 p0=1e6, min_visits: int = DEFAULT_MIN_VISITS,
                 interaction_radius: float = 60.0, profile_size: int = 6,
                 stats_window: int = 500, windup: str = 'directional', basis: RbfBasis = None,
                 robust: bool = False, alignment: bool = False, alignment_radius: float = 40.0,
                 alignment_size: int = 4, alignment_neighbourhood: str = 'radius',
                 alignment_nearest: int = 7, regime_window: int = 0,
                 range_pulls: bool = True):
        agents = [str(a) for a in agents]
        if len(agents) < 1 or len(set(agents)) != len(agents):
            raise HerdInputError(f'agents must be a non-empty list of distinct ids, got {agents}')
        if not (np.isfinite(dt) and dt > 0):
            raise HerdInputError(f'dt must be a positive number of seconds, got {dt}')
        if law not in LAWS:
            raise HerdInputError(f'law must be one of {LAWS}, got {law!r}')
        self.agents, self.dt, self.law = agents, float(dt), law
        self.grid = FieldGrid(int(field_grid[0]), int(field_grid[1]),
                              tuple(float(b) for b in field_bounds))
        self.basis = basis if basis is not None else RbfBasis.from_grid(self.grid)
        if law == 'pairwise':
            self.regressor = PairwiseRegressor(agents, self.basis)
        else:
            self.profile = DistanceProfile.even(interaction_radius, int(profile_size))
            self.regressor = SharedRegressor(agents, self.basis, self.profile)
        kernel = None
        if alignment:
            from herd_ros.model.alignment import AlignmentKernel
            kernel = AlignmentKernel.even(alignment_radius, int(alignment_size),
                                          alignment_neighbourhood, int(alignment_nearest))
            self.regressor = AlignedRegressor(self.regressor, kernel)
        self.min_visits = int(min_visits)
        self.range_pulls = bool(range_pulls)        # home and place pulls (module docstring)
        self.stats_window = int(stats_window)
        self.robust = bool(robust)
        self.rls = HerdRLS(len(agents), self.regressor.n_params, forgetting, p0, windup=windup)
        self.config = {'agents': agents, 'dt': self.dt, 'law': law,
                       'n_params': self.regressor.n_params,
                       'field_grid': [self.grid.nx, self.grid.ny],
                       'field_bounds': list(self.grid.bounds),
                       'interaction_radius': float(interaction_radius),
                       'profile_size': int(profile_size), 'robust': self.robust}
        if kernel is not None:      # (absent without: checkpoints from before stay readable)
            self.config.update(alignment_size=kernel.size,
                               alignment_radius=float(alignment_radius),
                               alignment_neighbourhood=kernel.neighbourhood,
                               alignment_nearest=int(kernel.nearest))
        # the residual window of the noise regimes (online_regimes; 0 = none): not part of
        # the configuration a checkpoint must match, and not in the checkpoint (refitted)
        from herd_ros.estimation.online_regimes import ResidualWindow
        self.residual_window = (ResidualWindow(len(agents), regime_window)
                                if int(regime_window) > 0 else None)
        self._reset_stream()      # (sets noise_regimes: (covariances, transition) or None)

    def structure(self):
        """The :class:`~herd_ros.model.model_structure.ModelStructure` a reader of
        :attr:`theta` needs (published beside it, so no reader restates it)."""
        from herd_ros.model.model_structure import ModelStructure
        c = self.config
        return ModelStructure(c['agents'], c['dt'], c['law'], c['field_grid'],
                              c['field_bounds'], c['interaction_radius'], c['profile_size'],
                              c.get('alignment_size', 0), c.get('alignment_radius', 0.0),
                              c.get('alignment_neighbourhood', 'radius'),
                              c.get('alignment_nearest', 7))

    # -- state -----------------------------------------------------------------------------
    def _reset_stream(self):
        n = len(self.agents)
        self.buffer_times: list[float] = []
        self.buffer_positions: list[np.ndarray] = []
        self._rows_memo = None
        self.last_seen = np.full((n, 2), np.nan)
        self.visits = np.zeros((n, self.basis.size), dtype=np.int64)
        # running moments of each agent's positions on the model clock (decayed by the
        # forgetting factor): weight, Σ p, Σ p pᵀ — the home range of the space-use pull
        self.pos_w = np.zeros(n)
        self.pos_sum = np.zeros((n, 2))
        self.pos_sq = np.zeros((n, 2, 2))
        # ... and of each agent's offset from the others' centroid (its place in the herd)
        self.place_w = np.zeros(n)
        self.place_sum = np.zeros((n, 2))
        self.place_sq = np.zeros((n, 2, 2))
        self.stat_sq = np.zeros(n)          # decayed Σ ‖e‖²
        self.stat_w = np.zeros(n)           # decayed Σ 1
        self.stat_lag = np.zeros((n, 2))    # decayed Σ e_t e_{t−1}
        self.stat_var = np.zeros((n, 2))    # decayed Σ e_t² (over pairs)
        self.stat_pairs = np.zeros(n)       # decayed count of pairs
        self.prev_residual = np.full((n, 2), np.nan)
        # prequential skill: Σ squared one-step position errors (m²) of the model (predicted
        # before the update), constant velocity and stay-put, and their count
        # the session: the herd (agents, in config) and the stretch of data time learned
        # from — which recording this state belongs to (checkpoints carry it)
        self.session = {'first_time': None, 'last_time': None, 'snapshots': 0}
        self.skill_sq = np.zeros((3, n))
        self.skill_n = np.zeros(n)
        if self.residual_window is not None:
            self.residual_window.clear()
        self.noise_regimes = None

    def reset(self):
        """Forget everything learned (θ = θ₀, P = P₀, counters and statistics zero)."""
        self.rls.reset()
        self._reset_stream()

    def break_chain(self):
        """The next snapshot starts a new chain (e.g. a new run)."""
        self.buffer_times, self.buffer_positions = [], []
        self.prev_residual[:] = np.nan

    @property
    def samples(self) -> np.ndarray:
        """Snapshots each agent has been updated with (N,)."""
        return self.rls.samples

    @property
    def theta(self) -> np.ndarray:
        """The current estimate θ (agent × param)."""
        return self.rls.theta

    def labels(self) -> list[str]:
        """The names of θ_i's entries, in order."""
        return self.regressor.labels()

    # -- the stream ------------------------------------------------------------------------
    def add_snapshot(self, t: float, positions: np.ndarray) -> SnapshotResult:
        """Take the herd snapshot at time ``t`` (s): positions (N, 2), NaN = missing."""
        p = np.asarray(positions, dtype=float)
        if p.shape != (len(self.agents), 2):
            raise HerdInputError(f'snapshot has shape {p.shape}, expected '
                                 f'({len(self.agents)}, 2) in agents order')
        sess = self.session
        if self.buffer_times:
            step = t - self.buffer_times[-1]
            if step <= 0:
                return SnapshotResult('backwards', step=step)
            if step < self.dt * (1.0 - STEP_TOLERANCE):
                # a herd clock finer than the model (gps_ingest ticking every second for a
                # fresh /herd/poses, the law learned at the collars' interval): the model
                # pairs snapshots one of its steps apart and skips those in between
                return SnapshotResult('between', step=step)
        sess['first_time'] = t if sess['first_time'] is None else sess['first_time']
        sess['last_time'], sess['snapshots'] = t, sess['snapshots'] + 1
        if self.buffer_times:
            if abs(step - self.dt) > STEP_TOLERANCE * self.dt:
                self.break_chain()
                self._push(t, p)
                if self.residual_window is not None:
                    self.residual_window.push(None)         # a missing emission
                return SnapshotResult('gap', step=step)
        self._push(t, p)
        if len(self.buffer_times) < 3:
            return SnapshotResult('primed')
        p0, p1, p2 = self.buffer_positions
        H, valid = self._rows(p0, p1)
        missing = ~np.isfinite(p0).all(axis=1)
        valid &= ~self.regressor.missing_neighbors(missing, self.last_seen, p0)
        y = (p2 - p1) / self.dt
        before = self.rls.sq_residual.copy() if self.residual_window is not None else None
        if self.robust:
            weight = self._outlier_weights(H, y)
            root = np.sqrt(weight)
            e = self.rls.update(H * root[:, None, None], y * root[:, None], valid) \
                / np.where(root > 0, root, 1.0)[:, None]
        else:
            e = self.rls.update(H, y, valid)
        used = np.isfinite(e).all(axis=1)
        self._count_visits(p0, used)
        self._update_stats(e, used)
        self._update_skill(e, H[:, :, 0], y, used)
        if self.residual_window is not None:
            # the standardized innovations ε = L⁻¹e of this update (cov Q_i, not inflated by
            # the parameters' uncertainty early on): the RLS adds ε εᵀ to its residual sum
            from herd_ros.estimation.online_regimes import rank_one_factor
            # (an agent's first p updates are left out: while θ_i is still unidentified its
            # standardized innovations are near zero, not noise)
            outer = self.rls.sq_residual - self.rls.forgetting * before
            settled = used & (self.rls.samples > self.regressor.n_params)
            self.residual_window.push(np.where(settled[:, None], rank_one_factor(outer),
                                               np.nan))
        self.buffer_times.pop(0)
        self.buffer_positions.pop(0)
        return SnapshotResult('updated', used, e, self.dt)

    def _update_skill(self, e, u_prev, y, used):
        """Prequential one-step errors (Dawid 1984: each prediction made before its data
        is learned from): model Δt·e (e the a-priori residual), constant velocity
        Δt·(u^{τ+1} − u^τ), stay-put Δt·u^{τ+1}; u^τ is the damping regressor."""
        dt2 = self.dt ** 2
        self.skill_sq[0, used] += dt2 * (e[used] ** 2).sum(1)
        self.skill_sq[1, used] += dt2 * ((y[used] - u_prev[used]) ** 2).sum(1)
        self.skill_sq[2, used] += dt2 * (y[used] ** 2).sum(1)
        self.skill_n[used] += 1

    def skill(self) -> dict:
        """Running one-step RMS (m) since the start, per agent and for the herd, of the
        estimator's own predictions (made before each update), constant velocity and
        stay-put: {'model'|'constant_velocity'|'stay_put': (N,) array, '…_herd': float,
        'predictions': (N,)}."""
        out = {'predictions': self.skill_n.copy()}
        total = self.skill_n.sum()
        with np.errstate(invalid='ignore', divide='ignore'):
            for k, name in enumerate(('model', 'constant_velocity', 'stay_put')):
                out[name] = np.sqrt(self.skill_sq[k] / self.skill_n)
                out[f'{name}_herd'] = (float(np.sqrt(self.skill_sq[k].sum() / total))
                                       if total else float('nan'))
        return out

    def _outlier_weights(self, H, y):
        """ω (N,) of each agent's update: the robust Kalman update of Chang (2014, see
        :mod:`herd_ros.estimation.robust`) inflates the noise covariance Q_i of an update
        by the factor λ ≥ 1 that brings the Mahalanobis distance² of its a-priori innovation
        e = y − Hθ, under S(λ) = σ̂_i² H P_i Hᵀ + λ Q_i, down to χ²₂(0.95); ω = 1/λ scales
        the rows. (Inflating Q by d²/c alone is not enough for a leverage point — the step
        out of a burst, whose regressor is a 1 km jump: H P Hᵀ is then large itself and the
        update still dragged the damping from 0.92 to 0.31, measured.) 1 until the agent
        has 3p updates (no Q to judge by yet)."""
        from herd_ros.estimation.robust import OUTLIER_CHI2
        rls = self.rls
        e = y - np.einsum('nkp,np->nk', H, rls.theta)
        q = rls.noise_cov()
        sigma2 = np.trace(q, axis1=1, axis2=2) / 2.0
        hph = sigma2[:, None, None] * np.einsum('nkp,npq,nlq->nkl', H, rls.P, H)
        ok = (np.isfinite(e).all(axis=1) & np.isfinite(hph).all(axis=(1, 2))
              & (rls.samples >= 3 * rls.n_params) & (np.trace(q, axis1=1, axis2=2) > 0))
        lam = np.ones(len(e))
        if ok.any():
            e_o, hph_o, q_o = e[ok], hph[ok], q[ok]
            lam_o = np.ones(len(e_o))
            for _ in range(60):                      # λ ← λ d²(λ)/c: d² falls as λ grows
                S = hph_o + lam_o[:, None, None] * q_o
                d2 = np.einsum('ni,nij,nj->n', e_o, np.linalg.pinv(S), e_o)
                grow = d2 > OUTLIER_CHI2 * (1 + 1e-6)
                if not grow.any():
                    break
                lam_o[grow] *= d2[grow] / OUTLIER_CHI2
            lam[ok] = lam_o
        return 1.0 / lam

    def _rows(self, p_prev, p_cur):
        """The regressor's rows of (p^τ, p^{τ+1}), formed once: the prediction after a
        snapshot needs the rows the next snapshot's update uses (the same buffered arrays)."""
        memo = self._rows_memo
        if memo is not None and memo[0] is p_prev and memo[1] is p_cur:
            return memo[2], memo[3].copy()
        H, valid = self.regressor.rows(p_prev, p_cur, self.dt)
        self._rows_memo = (p_prev, p_cur, H, valid.copy())
        return H, valid

    def _push(self, t, p):
        self.buffer_times.append(float(t))
        self.buffer_positions.append(p.copy())
        seen = np.isfinite(p).all(axis=1)
        self.last_seen[seen] = p[seen]
        lam = self.rls.forgetting
        for (w, s, sq), x in (((self.pos_w, self.pos_sum, self.pos_sq), p),
                              ((self.place_w, self.place_sum, self.place_sq),
                               place_offsets(p))):
            ok = np.isfinite(x).all(axis=1)
            q = x[ok]
            w[ok] = lam * w[ok] + 1.0
            s[ok] = lam * s[ok] + q
            sq[ok] = lam * sq[ok] + q[:, :, None] * q[:, None, :]

    def _count_visits(self, p0, used):
        xmin, xmax, ymin, ymax = self.grid.bounds
        sx, sy = self.grid.spacing
        q = np.nan_to_num(p0[used], nan=-np.inf)
        ix = np.floor((q[:, 0] - xmin) / sx)
        iy = np.floor((q[:, 1] - ymin) / sy)
        inside = (ix >= 0) & (ix < self.grid.nx) & (iy >= 0) & (iy < self.grid.ny)
        if self.basis.size != self.grid.nx * self.grid.ny:
            return  # a custom basis: no grid cells to count
        rows = np.flatnonzero(used)[inside]
        cells = (iy[inside] * self.grid.nx + ix[inside]).astype(np.int64)
        self.visits[rows, cells] += 1

    def _update_stats(self, e, used):
        decay = 1.0 - 1.0 / self.stats_window
        eu = e[used]
        self.stat_sq[used] = decay * self.stat_sq[used] + (eu ** 2).sum(1)
        self.stat_w[used] = decay * self.stat_w[used] + 1.0
        prev = self.prev_residual[used]
        pair = np.isfinite(prev).all(axis=1)
        idx = np.flatnonzero(used)[pair]
        self.stat_lag[idx] = decay * self.stat_lag[idx] + eu[pair] * prev[pair]
        self.stat_var[idx] = decay * self.stat_var[idx] + eu[pair] ** 2
        self.stat_pairs[idx] = decay * self.stat_pairs[idx] + 1.0
        self.prev_residual[:] = np.nan
        self.prev_residual[used] = eu

    # -- what it says ----------------------------------------------------------------------
    def predict(self):
        """One-step-ahead positions (eq. 8) from the last two snapshots: (t + Δt, (N, 2)).

        p̂^{τ+2} = p^{τ+1} + Δt H(p^τ, p^{τ+1}) θ; None before two snapshots of a chain.
        """
        if len(self.buffer_times) < 2:
            return None
        p0, p1 = self.buffer_positions[-2], self.buffer_positions[-1]
        H, _ = self._rows(p0, p1)
        u_next = np.einsum('nkp,np->nk', H, self.rls.theta)
        return self.buffer_times[-1] + self.dt, p1 + self.dt * u_next

    def diagnostics(self) -> dict:
        """Per-agent arrays: samples, residual_rms, lag1_autocorrelation, white_band, white,
        condition (of P_i)."""
        with np.errstate(invalid='ignore', divide='ignore'):
            rms = np.sqrt(self.stat_sq / self.stat_w)
            r1 = (self.stat_lag / self.stat_var).mean(axis=1)
            band = 1.96 / np.sqrt(self.stat_pairs)
        return {'samples': self.rls.samples.copy(), 'residual_rms': rms,
                'lag1_autocorrelation': r1, 'white_band': band,
                'white': np.abs(r1) < band, 'condition': self.rls.condition()}

    def mean_field(self, points: np.ndarray) -> np.ndarray:
        """The herd's mean environment field Σ_k [θ̄u_k, θ̄v_k] φ_k(p) at ``points`` (M, 2)."""
        o, K = self.regressor.field_offset, self.basis.size
        coef = self.rls.theta[:, o:o + 2 * K].mean(axis=0)
        phi = self.basis.features(points)
        return np.column_stack([phi @ coef[:K], phi @ coef[K:]])

    def kept_centers(self) -> list[np.ndarray]:
        """Lazy pruning: per agent, the centres whose cell it visited ≥ min_visits times."""
        out = []
        for i in range(len(self.agents)):
            keep = self.visits[i] >= self.min_visits
            if not keep.any():
                keep = np.ones(self.basis.size, dtype=bool)  # nothing learned: keep all (θ₀)
            out.append(keep)
        return out

    def pruned_estimate(self, keeps, standard_errors: bool = True):
        """θ and its standard errors with the coefficients of dropped centres set to zero.

        The RLS state is the quadratic form of the least-squares cost,
        J(θ) = (θ − θ̂)ᵀ P⁻¹ (θ − θ̂) + const, so fixing the dropped entries θ_d = 0 and
        minimising over the kept ones gives (the conditional Gaussian mean)

            θ_k = θ̂_k − P_kd P_dd⁻¹ θ̂_d,   Cov θ_k = C_kk − C_kd C_dd⁻¹ C_dk,

        i.e. the least-squares fit on the kept basis alone, without revisiting the data.
        One small solve per agent. Without ``standard_errors`` (what is published after every
        update needs θ only) the errors are None.
        """
        o, K = self.regressor.field_offset, self.basis.size
        theta = self.rls.theta.copy()
        cov = se = None
        if standard_errors:
            cov = self.rls.theta_cov()
            se = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
        for i, keep in enumerate(keeps):
            drop = np.zeros(self.rls.n_params, dtype=bool)
            drop[o:o + K] = drop[o + K:o + 2 * K] = ~keep
            if not drop.any():
                continue
            kept = ~drop
            P = self.rls.P[i]
            gain = np.linalg.solve(P[np.ix_(drop, drop)], P[np.ix_(drop, kept)]).T
            theta[i, kept] -= gain @ theta[i, drop]
            theta[i, drop] = 0.0
            if standard_errors:
                c = cov[i]
                ck = c[np.ix_(kept, kept)] - gain @ c[np.ix_(drop, kept)]
                se[i, kept] = np.sqrt(np.clip(np.diag(ck), 0, None))
        return theta, se

    def refit_noise_regimes(self):
        """Refit the noise regimes on the residual window
        (:func:`~herd_ros.estimation.online_regimes.fit_residuals`); the fit summary, or None
        (no window, or no agent with ``MIN_RESIDUALS`` residuals in it yet).
        :attr:`noise_regimes` is then the fitted (covariances, transition), or None when
        one regime (Gaussian noise) is kept."""
        residuals = self.regime_residuals()
        if residuals is None:
            return None
        from herd_ros.estimation.online_regimes import fit_residuals
        return self.adopt_regimes(fit_residuals(residuals))

    def regime_residuals(self):
        """A copy of the residual window (T, N, 2) ready for a regime fit, or None (no
        window, or no agent with ``MIN_RESIDUALS`` residuals in it yet)."""
        from herd_ros.estimation.online_regimes import MIN_RESIDUALS
        if self.residual_window is None or \
                self.residual_window.counts().max(initial=0) < MIN_RESIDUALS:
            return None
        return self.residual_window.residuals()

    def adopt_regimes(self, got):
        """Take the result of :func:`~herd_ros.estimation.online_regimes.fit_residuals`
        ((covariances, transition, fit) or None); the fit summary or None."""
        if got is None:
            return None
        cov, trans, fit = got
        self.noise_regimes = (cov, trans) if fit['n_regimes'] > 1 else None
        return fit

    def published_regimes(self):
        """(covariances (N, K, 2, 2), transition (N, K, K)) of the noise as it is published:
        the fitted regimes, or Q_i as one regime (Gaussian noise) when one was kept."""
        if self.noise_regimes is not None:
            return self.noise_regimes
        n = len(self.agents)
        return self.rls.noise_cov().reshape(n, 1, 2, 2), np.ones((n, 1, 1))

    def published_law(self):
        """What the ``estimator`` node publishes, the law of the model file: θ (agent ×
        param) with the field centres an agent has not visited ``min_visits`` times at
        zero and the rest re-solved (:meth:`pruned_estimate`: a field bounded to the data,
        not the prior's guesses where the herd never was), and the home pull (μ, K, Σ) of
        :meth:`home_pull` for that θ and the noise the robots draw (the stationary mean of
        :meth:`published_regimes`: the herd's present pace)."""
        from herd_ros.model.noise_regimes import stationary_mean
        theta, _ = self.pruned_estimate(self.kept_centers(), standard_errors=False)
        noise = stationary_mean(*self.published_regimes())
        return theta, self.home_pull(theta, noise), self.herd_place(theta, noise)

    def home_pull(self, theta=None, noise=None):
        """Each animal's range and the pull that keeps the law in it: (μ (N, 2), K (N, 2,
        2), Σ (N, 2, 2)), the running mean and covariance of its positions so far (on the
        model clock, weighted by the forgetting factor) and the gain of (S2) of
        :mod:`herd_ros.model.space_use_field`, K_i = Δt/(2(1 − a_i)) Q_i Σ_i⁻¹ — the
        Ornstein-Uhlenbeck pull of the Gaussian home range — applied at the range's edge
        (:func:`~herd_ros.model.space_use_field.home_drift`: beyond the Mahalanobis radius
        2). K_i = 0 for an agent with fewer than ``MIN_HOME_POSITIONS`` positions,
        positions that do not spread, or a law without a stationary state (a_i ≥ 1), and
        for all with ``range_pulls=False``. ``theta`` (N, p): the law it joins (default:
        the current estimate); ``noise`` (N, 2, 2): the noise that law draws (default:
        Q_i)."""
        return self._range(self.pos_w, self.pos_sum, self.pos_sq, theta, noise)

    def herd_place(self, theta=None, noise=None):
        """Each animal's place in the herd, (m (N, 2), K (N, 2, 2), S (N, 2, 2)) of (P1) of
        :mod:`herd_ros.model.herd_place`: the running mean and covariance of its offset
        from the others' centroid and the gain of the pull at that range's edge (the home
        pull of :meth:`home_pull` in the herd's frame: a travelling herd's robots keep
        together). Same conditions and arguments as :meth:`home_pull`."""
        return self._range(self.place_w, self.place_sum, self.place_sq, theta, noise,
                           coupling=place_coupling(len(self.agents)))

    def _range(self, w, total, sq, theta, noise, coupling: float = 1.0):
        """(mean, gain, covariance) of running moments (weight, Σ x, Σ x xᵀ)."""
        n = len(self.agents)
        a = (self.rls.theta if theta is None else np.asarray(theta, dtype=float))[:, 0]
        with np.errstate(invalid='ignore', divide='ignore'):
            mu = np.nan_to_num(total / w[:, None])
            cov = np.nan_to_num(sq / w[:, None, None] - mu[:, :, None] * mu[:, None, :])
        q = self.rls.noise_cov() if noise is None else np.asarray(noise, dtype=float)
        if not self.range_pulls:                   # the ranges kept, no pull
            w = np.zeros_like(w)
        return range_gain(w, mu, cov, a, q.reshape(n, 2, 2), self.dt, MIN_HOME_POSITIONS,
                          coupling)

    def model(self, frame_id: str = 'map', datum=None):
        """The current estimate as a model (HerdModel or SharedLawModel), lazily pruned;
        with the noise regimes when they have been fitted, scaled so that their stationary
        mean is the model's Q_i (as the regimes of a fitted model file are)."""
        import dataclasses
        keeps = self.kept_centers()
        theta, se = self.pruned_estimate(keeps)
        noise_cov = self.rls.noise_cov()
        model = self.regressor.to_model(theta, se, noise_cov, keeps, self.dt, frame_id, datum)
        meta = dict(model.meta or {})
        for key, (mu, gain, cov) in (('space_use_home', self.home_pull(theta)),
                                     ('herd_place', self.herd_place(theta))):
            if gain.any():
                meta[key] = (mu, gain, cov)
        if self.noise_regimes is not None:
            from herd_ros.model.noise_regimes import regimes_scaled_to
            cov, trans = self.noise_regimes
            meta['noise_regimes'] = (regimes_scaled_to(cov, trans, noise_cov), trans)
        return dataclasses.replace(model, meta=meta)

    def save_model(self, path, frame_id: str = 'map', datum=None):
        """Write the model file (``schwager2007`` or ``schwager2007_shared``) atomically."""
        from herd_ros.model.kinds import save
        return save(self.model(frame_id, datum), path)

    # -- checkpoints -----------------------------------------------------------------------
    def state(self) -> dict:
        """Everything a checkpoint needs to resume (arrays by name): the RLS state, the last
        three snapshots and the running statistics."""
        n = len(self.agents)
        buf_t = np.full(3, np.nan)
        buf_p = np.full((3, n, 2), np.nan)
        times, positions = self.buffer_times[-3:], self.buffer_positions[-3:]
        k = len(times)
        buf_t[:k] = times
        if k:
            buf_p[:k] = np.stack(positions)
        arrays = {f'rls_{key}': v for key, v in self.rls.state().items()}
        arrays.update(buffer_times=buf_t, buffer_positions=buf_p, last_seen=self.last_seen,
                      visits=self.visits, pos_w=self.pos_w, pos_sum=self.pos_sum,
                      pos_sq=self.pos_sq, place_w=self.place_w, place_sum=self.place_sum,
                      place_sq=self.place_sq, stat_sq=self.stat_sq, stat_w=self.stat_w,
                      stat_lag=self.stat_lag, stat_var=self.stat_var,
                      stat_pairs=self.stat_pairs, prev_residual=self.prev_residual,
                      skill_sq=self.skill_sq, skill_n=self.skill_n,
                      config=np.array(json.dumps(self.config)),
                      session=np.array(json.dumps(self.session)))
        return arrays

    def save_checkpoint(self, path) -> Path:
        """Write the whole state to ``path`` (.npz) by write-then-rename."""
        with atomic_open(path, 'wb') as fh:
            np.savez(fh, **self.state())
        return Path(path)

    def load_checkpoint(self, path) -> bool:
        """Resume from ``path`` if it exists; False if absent. Raises HerdInputError when the
        file is unreadable or was written for another configuration (agents, law, dt, grid)."""
        path = Path(path)
        if not path.is_file():
            return False
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
            config = json.loads(str(data['config']))
        except (OSError, ValueError, KeyError) as exc:
            raise HerdInputError(f'{path}: not a readable estimator checkpoint ({exc})') from None
        config.setdefault('robust', False)          # checkpoints from before the option
        differ = [k for k in self.config if config.get(k) != self.config[k]]
        if differ:
            raise HerdInputError(f'{path}: checkpoint was written for another configuration '
                                 f'({", ".join(differ)} differ)')
        self.rls.load_state({k[4:]: v for k, v in data.items() if k.startswith('rls_')})
        k = int(np.isfinite(data['buffer_times']).sum())
        self.buffer_times = [float(t) for t in data['buffer_times'][:k]]
        self.buffer_positions = [p.copy() for p in data['buffer_positions'][:k]]
        for key in ('last_seen', 'visits', 'stat_sq', 'stat_w', 'stat_lag', 'stat_var',
                    'stat_pairs', 'prev_residual'):
            setattr(self, key, np.array(data[key]))
        # (absent from older checkpoints)
        for key in ('skill_sq', 'skill_n', 'pos_w', 'pos_sum', 'pos_sq', 'place_w',
                    'place_sum', 'place_sq'):
            if key in data:
                setattr(self, key, np.array(data[key]))
        if 'session' in data:
            self.session = json.loads(str(data['session']))
        return True

    def describe_session(self) -> str:
        """The herd and the stretch of data time this state was learned from."""
        s = self.session
        if s['first_time'] is None:
            return f'herd of {len(self.agents)} ({", ".join(self.agents[:3])}' + (
                ', ...)' if len(self.agents) > 3 else ')') + ', no data yet'
        return (f'herd of {len(self.agents)} ({", ".join(self.agents[:3])}'
                + (', ...' if len(self.agents) > 3 else '') + f'), data time '
                f'{s["first_time"]:.3f} to {s["last_time"]:.3f} s, {s["snapshots"]} snapshots')


# -- offline driver: `herd-ros fit --online` ------------------------------------------------
@dataclass
class OnlineFitResult:
    """What ``herd-ros fit --online`` learned: the estimator and θ over time (rows at ``times``,
    per ``runs`` label)."""
    estimator: OnlineHerdEstimator
    times: np.ndarray          # (R,) times of the recorded rows
    runs: list                 # (R,) run label of each row
    theta: np.ndarray          # (R, N, p)
    samples: np.ndarray        # (R, N)


def online_fit(runs, law: str = 'pairwise', grid=(6, 6), bounds=None, forgetting: float = 1.0,
               p0=1e6, record_every: int | None = None, progress=None, **kwargs) -> OnlineFitResult:
    """Run the online estimator over trajectory runs (the rows the batch fit uses).

    Args:
        runs: list of :class:`HerdTrajectory` with the same agents and clock.
        bounds: field bounds; default the bounding box of all positions.
        record_every: record θ every this many steps (default: about 1000 rows per run).
        progress: optional callable(n_steps) for a progress bar.
    """
    from herd_ros.estimation.herd_fit import aligned_positions, check_runs
    agents, dt = check_runs(runs)
    positions = [aligned_positions(r, agents) for r in runs]
    if bounds is None:
        pts = np.concatenate([p.reshape(-1, 2) for p in positions])
        bounds = FieldGrid.over(pts[np.isfinite(pts).all(-1)], grid[0], grid[1]).bounds
    est = OnlineHerdEstimator(agents, dt, law, grid, bounds, forgetting, p0, **kwargs)
    times, labels, thetas, samples = [], [], [], []
    for run, p in zip(runs, positions):
        every = record_every or max(1, len(p) // 1000)
        est.break_chain()
        for k in range(len(p)):
            est.add_snapshot(float(run.times[k]), p[k])
            if (k + 1) % every == 0 or k == len(p) - 1:
                times.append(float(run.times[k]))
                labels.append(run.run)
                thetas.append(est.theta.copy())
                samples.append(est.samples.copy())
            if progress is not None and (k + 1) % 1000 == 0:
                progress(1000)
    return OnlineFitResult(est, np.array(times), labels, np.array(thetas), np.array(samples))


def write_params_csv(result: OnlineFitResult, path) -> Path:
    """Parameters over time: ``time,run,agent,samples,<labels>`` (one row per agent and time).

    Pairwise labels: ``theta1_k``/``theta2_k`` refer to the k-th neighbour in the agent's
    ``neighbors`` list of the model file (the other agents in ``agents`` order).
    """
    import pandas as pd
    est = result.estimator
    R, N, p = result.theta.shape
    frame = pd.DataFrame(result.theta.reshape(R * N, p), columns=est.labels())
    frame.insert(0, 'samples', result.samples.reshape(R * N))
    frame.insert(0, 'agent', np.tile(est.agents, R))
    frame.insert(0, 'run', np.repeat(np.array([r if r is not None else '' for r in result.runs],
                                              dtype=object), N))
    frame.insert(0, 'time', np.repeat(result.times, N))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.to_csv(path, index=False, float_format='%.10g')
    return path
