"""Learn a swarm policy from trajectories (Rahman, White et al., ACC 2023, Sec. III).

Model (see :mod:`herd_ros.imitation.boids`): ``v_i^τ = σ_vmax(Σ_k k_k θ_k,i(p^τ, v^{τ−1}))``,
``p^{τ+1} = p^τ + Δt v^τ``. Only noisy positions ``q^τ = p^τ + η^τ`` are observed.

Pipeline (:func:`learn_policy`):

1. **Velocities** ``y^τ = (q^{τ+1} − q^τ)/Δt`` (forward difference: exact for a single
   integrator, so y^τ = v^τ + (η^{τ+1} − η^τ)/Δt). Sample τ of agent i has target y_i^τ and
   features θ(q^τ, y^{τ−1}).
2. **v_max**: the 99th percentile of observed speeds (the paper), unless the speeds show a
   saturation cluster — then the *half-sample mode* (Bickel & Frühwirth 2006) of the upper half
   of the speeds, which sits on v_max whatever the share of unsaturated samples below it
   (a percentile moves with the noise and with that share). See :func:`estimate_v_max`.
3. **Radius** r: one-dimensional search of the one-step MAE. The loss is piecewise constant
   in r (it changes only where r crosses a pairwise distance), so derivative-based or golden
   section searches stall on plateaus; we use a coarse grid over [r_lo, r_hi] and zoom three
   times around the best point (each level a 9-point grid over ±1 coarse step), taking the
   middle of the tied minimisers at the end. Per r, gains come from a fast least-squares fit
   on unsaturated samples. Neighbour pairs are computed once at r_hi and sorted by distance,
   so each r costs only prefix sums. See :func:`search_radius`.
4. **Gains**: linear regression on unsaturated samples, then SLSQP on the saturated model over
   all samples; optional second pass keeping policies with |k| ≥ 0.1.

**Errors in variables.** The features are built from the same noisy positions as the target:
the own position q_i^τ enters both θ_i^τ (cohesion, separation, ...) and y_i^τ (with −1/Δt),
and the own previous velocity y_i^{τ−1} (inertia, heading) shares η_i^τ with y_i^τ. So the
target noise is correlated with the regressor noise, and regressor noise also attenuates the
gains — ordinary least squares is biased, badly so when velocity noise √2σ/Δt is comparable
with the speeds (5 % of v_max·Δt already gives 0.5 m/s in the paper case). We use
**instrumental variables** (``errors_in_variables='iv'``, default): the instruments for the
features at step τ are the same features at step τ−2, built from q^{τ−2} and y^{τ−3} — samples
that share no noise with the target (η^τ, η^{τ+1}) nor with the regressors (η^{τ−1}, η^τ) but
are strongly correlated with the true features because the swarm moves smoothly over 2Δt.
The linear stage is two-stage least squares k = (ZᵀX)⁻¹Zᵀy; the SLSQP stage minimises the
nonlinear 2SLS objective (Amemiya 1974) ``eᵀZ(ZᵀZ)⁻¹Zᵀe`` with e = y − σ_vmax(Xk), whose
minimiser sets the instrument moments Zᵀe to zero. Lagging (rather than smoothing positions)
adds no deterministic error: the regressors stay exactly θ(q^τ, y^{τ−1}). ``'none'`` gives the
naive least-squares fit for comparison. Standard errors are sandwich estimates clustered by
(run, agent) track, since the differenced noise makes consecutive residuals correlated.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from herd_ros.errors import HerdInputError
from herd_ros.imitation.boids import ImitationPolicy, saturate
from herd_ros.imitation.metrics import mae
from herd_ros.imitation.policies import (RadiusFeatures, check_policies, check_walls,
                                         pair_geometry)
from herd_ros.trajectory import HerdTrajectory

LAG = 2  # instruments: features two steps earlier (and EXTRA_LAGS more, over-identifying)
EXTRA_LAGS = (3, 4)


def velocities_from_positions(positions: np.ndarray, dt: float) -> np.ndarray:
    """Forward differences y^τ = (q^{τ+1} − q^τ)/Δt: (T, N, 2) m -> (T−1, N, 2) m/s."""
    return np.diff(np.asarray(positions, dtype=float), axis=0) / dt


@dataclass
class SampleSet:
    """Flat samples (agent i at step τ ≥ 1 of a run) with their targets and lagged partners.

    Attributes (S samples): positions q^τ (S, 2); previous velocities y^{τ−1} (S, 2); targets
    y^τ (S, 2); ``lagged`` (S,) index of the same agent at τ − LAG (−1 if none); ``track``
    (S,) a (run, agent) id for clustered errors; ``frame_sizes`` agents per frame; dt.
    """

    positions: np.ndarray
    previous: np.ndarray
    targets: np.ndarray
    lagged: np.ndarray
    track: np.ndarray
    frame_sizes: np.ndarray
    dt: float

    @property
    def usable(self) -> np.ndarray:
        """Samples with a lagged partner whose own previous velocity exists."""
        return (self.lagged >= 0).all(axis=1)


def build_samples(runs: list[HerdTrajectory]) -> SampleSet:
    """Stack every run's steps τ = 1 .. T−2 (target y^τ needs q^{τ+1}, features need y^{τ−1})."""
    if not runs:
        raise HerdInputError('no trajectory runs given')
    dts = np.array([r.dt for r in runs])
    dt = float(np.round(np.median(dts), 9))
    if np.any(np.abs(dts - dt) > 1e-6 * dt):
        raise HerdInputError(f'runs have different clock steps ({sorted(set(dts.tolist()))}); '
                             f'imitation needs one Δt')
    P, Vp, Y, lag, track, sizes = [], [], [], [], [], []
    offset, track0 = 0, 0
    for r in runs:
        q = np.asarray(r.positions, dtype=float)
        T, N = q.shape[:2]
        if T < max((LAG,) + EXTRA_LAGS) + 3 or N < 2:
            continue
        if not np.isfinite(q).all():
            raise HerdInputError(f'run {r.run!r}: positions contain NaN; resample first')
        y = velocities_from_positions(q, dt)                 # (T−1, N, 2)
        frames = np.arange(1, T - 1)                          # τ
        P.append(q[frames].reshape(-1, 2))
        Vp.append(y[frames - 1].reshape(-1, 2))
        Y.append(y[frames].reshape(-1, 2))
        local = np.arange(len(frames) * N)
        lags = (LAG,) + EXTRA_LAGS
        lg = offset + local[:, None] - np.array(lags)[None, :] * N
        lg[np.repeat(frames, N) < max(lags) + 1] = -1         # need τ − lag ≥ 1
        lag.append(lg)
        track.append(track0 + np.tile(np.arange(N), len(frames)))
        sizes.append(np.full(len(frames), N))
        offset += len(frames) * N
        track0 += N
    if not P:
        raise HerdInputError(f'every run is too short: need at least {LAG + 3} time steps and '
                             f'two agents')
    return SampleSet(np.concatenate(P), np.concatenate(Vp), np.concatenate(Y),
                     np.concatenate(lag), np.concatenate(track), np.concatenate(sizes), dt)


def half_sample_mode(x: np.ndarray) -> float:
    """Half-sample mode (Bickel & Frühwirth 2006): repeatedly keep the shortest interval holding
    half of the sorted sample; robust to asymmetric contamination."""
    x = np.sort(np.asarray(x, dtype=float))
    while len(x) > 3:
        h = (len(x) + 1) // 2
        widths = x[h - 1:] - x[:len(x) - h + 1]
        k = int(np.argmin(widths))
        x = x[k:k + h]
    return float(np.mean(x))


@dataclass
class VmaxEstimate:
    """The agents' top speed as estimated from the data, and how (the mode of the saturated
    speeds or a percentile)."""
    v_max: float
    percentile: float
    mode: float
    saturation_share: float   # share of samples within the saturation cluster
    method: str               # 'mode' or 'percentile'


def estimate_v_max(speeds: np.ndarray, *, percentile: float = 99.0,
                   cluster_width: float = 0.05, min_share: float = 0.1) -> VmaxEstimate:
    """Speed limit from observed speeds (m/s).

    ``percentile`` (the paper's estimator) is biased low when few samples saturate and high
    when the noise is large. If a saturation cluster exists — at least ``min_share`` of all
    samples within ±``cluster_width`` (relative) of the half-sample mode of the upper half of
    the speeds, and that mode lies in the upper quartile — the mode is returned instead.
    """
    s = np.asarray(speeds, dtype=float)
    s = s[np.isfinite(s)]
    pct = float(np.percentile(s, percentile))
    upper = s[s >= np.median(s)]
    mode = half_sample_mode(upper)
    share = float(np.mean(np.abs(s - mode) <= cluster_width * mode))
    if share >= min_share and mode >= np.percentile(s, 75):
        return VmaxEstimate(mode, pct, mode, share, 'mode')
    return VmaxEstimate(pct, pct, mode, share, 'percentile')


def _design(theta: np.ndarray) -> np.ndarray:
    """(n, K, 2) features -> (2n, K) rows [x-components; y-components interleaved]."""
    return np.ascontiguousarray(theta.transpose(0, 2, 1)).reshape(-1, theta.shape[1])


def _lstsq(X, y, cols):
    k = np.zeros(X.shape[1])
    if cols.any():
        k[cols] = np.linalg.lstsq(X[:, cols], y, rcond=None)[0]
    return k


def _iv(X, Z, y, cols):
    k = np.zeros(X.shape[1])
    if cols.any():
        Xc, Zc = X[:, cols], Z
        # 2SLS: first stage X̂ = Z (ZᵀZ)⁻¹ ZᵀX, then regress y on X̂
        Xhat = Zc @ np.linalg.lstsq(Zc, Xc, rcond=None)[0]
        k[cols] = np.linalg.lstsq(Xhat, y, rcond=None)[0]
    return k


def _saturated(u2: np.ndarray, v_max: float):
    """σ(u) and its Jacobian pieces for u (n, 2)."""
    speed = np.linalg.norm(u2, axis=1)
    sat = speed > v_max
    scale = np.where(sat, v_max / np.maximum(speed, 1e-300), 1.0)
    return u2 * scale[:, None], sat, scale, speed


def _prediction_jacobian(theta: np.ndarray, k: np.ndarray, v_max: float):
    """f = σ(Σ k θ) (n, 2) and ∂f/∂k (n, 2, K)."""
    u = np.einsum('nkd,k->nd', theta, k)
    f, sat, scale, speed = _saturated(u, v_max)
    uhat = u / np.maximum(speed, 1e-300)[:, None]
    # dσ/du = I (unsaturated) or (v/‖u‖)(I − ûûᵀ) (saturated)
    proj = theta - sat[:, None, None] * np.einsum('nd,nkd->nk', uhat, theta)[:, :, None] \
        * uhat[:, None, :]
    J = (scale[:, None, None] * proj).transpose(0, 2, 1)
    return f, J


@dataclass
class GainFit:
    """The fitted gains of a policy with their standard errors, the linear start and whether the
    fit converged."""
    gains: np.ndarray
    gains_se: np.ndarray
    linear_gains: np.ndarray
    success: bool
    message: str


def fit_gains(theta: np.ndarray, targets: np.ndarray, v_max: float, *,
              instruments: np.ndarray | None = None, tracks: np.ndarray | None = None,
              unsaturated_fraction: float = 0.9) -> GainFit:
    """Gains k for fixed features: regression on unsaturated samples, then SLSQP.

    Args:
        theta: (n, K, 2) features. targets: (n, 2) observed velocities (m/s).
        v_max: speed limit (m/s).
        instruments: (n, K, 2) lagged features for IV (None = least squares).
        tracks: (n,) cluster ids for the standard errors (None = every sample its own).
        unsaturated_fraction: samples with ‖y‖ < this·v_max feed the linear stage.

    The SLSQP objective is eᵀP e/n with e = y − σ_vmax(Xk) stacked (2n,), P = I (least
    squares) or P = Z(ZᵀZ)⁻¹Zᵀ (nonlinear 2SLS), with its analytic gradient. A policy whose
    feature is identically zero cannot be learned; its gain is 0 with a NaN standard error.
    """
    n, K, _ = theta.shape
    y2 = targets.reshape(-1)
    cols = np.abs(theta).reshape(n, -1).max(axis=0).reshape(K, 2).max(axis=1) > 0
    unsat = np.linalg.norm(targets, axis=1) < unsaturated_fraction * v_max
    if unsat.sum() < 2 * K:
        unsat = np.ones(n, bool)
    X = _design(theta)
    m2 = np.repeat(unsat, 2)
    if instruments is None:
        k0 = _lstsq(X[m2], y2[m2], cols)
        Z = None
    else:
        Zfull = _design(instruments)
        zcols = np.abs(Zfull).max(axis=0) > 0
        Z = Zfull[:, zcols]
        k0 = _iv(X[m2], Z[m2], y2[m2], cols)
    idx = np.flatnonzero(cols)
    if Z is not None:
        ZtZ_inv = np.linalg.pinv(Z.T @ Z)

    def objective(kc):
        k = np.zeros(K)
        k[idx] = kc
        f, J = _prediction_jacobian(theta, k, v_max)
        e = y2 - f.reshape(-1)
        D = J.reshape(-1, K)[:, idx]
        if Z is None:
            return e @ e / n, -2 * (D.T @ e) / n
        g = Z.T @ e
        Wg = ZtZ_inv @ g
        return g @ Wg / n, -2 * (D.T @ Z) @ Wg / n

    res = minimize(objective, k0[idx], jac=True, method='SLSQP',
                   options={'maxiter': 200, 'ftol': 1e-12})
    k = np.zeros(K)
    k[idx] = res.x
    # sandwich standard errors, clustered by track
    f, J = _prediction_jacobian(theta, k, v_max)
    e = y2 - f.reshape(-1)
    D = J.reshape(-1, K)[:, idx]
    Zs = D if Z is None else Z
    W = np.linalg.pinv(Zs.T @ Zs)
    A = np.linalg.pinv(D.T @ Zs @ W @ Zs.T @ D) @ (D.T @ Zs @ W)
    groups = np.repeat(np.arange(n) if tracks is None else np.asarray(tracks), 2)
    ze = Zs * e[:, None]
    _, inv = np.unique(groups, return_inverse=True)
    G = np.zeros((inv.max() + 1, Zs.shape[1]))
    np.add.at(G, inv, ze)
    cov = A @ (G.T @ G) @ A.T
    se = np.full(K, np.nan)
    se[idx] = np.sqrt(np.maximum(np.diag(cov), 0))
    return GainFit(k, se, k0, bool(res.success), str(res.message))


def refine_v_max(theta: np.ndarray, targets: np.ndarray, gains: np.ndarray, v_start: float,
                 *, tolerance: float = 1e-4) -> float:
    """Speed limit minimising the one-step mean squared error for fixed gains.

    MSE(v) = (1/n) Σ ‖σ_v(u_s) − y_s‖², u_s = Σ_k k_k θ_k,s, is continuous in v (unlike the
    radius loss) and unbiased by zero-mean target noise. With samples sorted by ‖u_s‖ it is,
    exactly, (1/n)[Σ_{‖u‖≤v} ‖u − y‖² + Σ_{‖u‖>v} (v² − 2v û·y + ‖y‖²)], so every candidate v
    costs O(log n) with cumulative sums. The MSE is flat once v exceeds every ‖u_s‖, where the
    data say nothing more about v_max: we return the smallest v whose MSE is within
    ``tolerance`` (relative) of the minimum over [v_start/2, max ‖u‖] — when saturation binds,
    the minimiser; otherwise the fastest speed the policy commands on the data.
    """
    u = np.einsum('nkd,k->nd', theta, gains)
    speed = np.sqrt(np.einsum('nd,nd->n', u, u))
    order = np.argsort(speed)
    sp = speed[order]
    uu, yy = u[order], targets[order]
    uhat_y = np.einsum('nd,nd->n', uu, yy) / np.maximum(sp, 1e-300)
    r_unsat = np.einsum('nd,nd->n', uu - yy, uu - yy)
    y2 = np.einsum('nd,nd->n', yy, yy)
    c_unsat = np.concatenate([[0.0], np.cumsum(r_unsat)])       # Σ over the first m
    def tail(x):                                                # Σ from m on
        return np.concatenate([np.cumsum(x[::-1])[::-1], [0.0]])
    b_sat, c_sat = tail(uhat_y), tail(y2)
    n = len(sp)
    hi = max(float(sp[-1]), v_start)
    grid = np.unique(np.concatenate([np.linspace(0.5 * v_start, hi, 4000),
                                     sp[sp >= 0.5 * v_start]]))
    m = np.searchsorted(sp, grid, side='right')                 # unsaturated count
    mse = (c_unsat[m] + (n - m) * grid ** 2 - 2 * grid * b_sat[m] + c_sat[m]) / n
    best = mse.min()
    return float(grid[mse <= best + tolerance * abs(best)].min())


@dataclass
class RadiusSearch:
    """The interaction radius chosen by one-step error, with every radius tried and its loss."""
    radius: float
    radii: np.ndarray     # every r evaluated, in evaluation order
    losses: np.ndarray    # one-step MAE at each
    bounds: tuple
    pairs: object = None  # the neighbour pairs up to the upper bound, for reuse


def _default_radius_bounds(samples: SampleSet) -> tuple[float, float]:
    """[median nearest-neighbour distance, 90th percentile of pairwise distances], from a
    subsample of frames."""
    sizes = samples.frame_sizes
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    pick = np.linspace(0, len(sizes) - 1, min(len(sizes), 50)).astype(int)
    nn, alld = [], []
    for f in pick:
        P = samples.positions[starts[f]:starts[f] + sizes[f]]
        d = np.linalg.norm(P[:, None] - P[None], axis=-1)
        iu = np.triu_indices(len(P), 1)
        alld.append(d[iu])
        np.fill_diagonal(d, np.inf)
        nn.append(d.min(axis=1))
    return float(np.median(np.concatenate(nn))), float(np.percentile(np.concatenate(alld), 90))


def search_radius(samples: SampleSet, policies, v_max: float, *, walls=None, bounds=None,
                  coarse: int = 16, zoom_levels: int = 3, zoom_points: int = 7,
                  pairs=None) -> RadiusSearch:
    """Coarse-to-fine grid search of the one-step MAE over r (see module docstring)."""
    lo, hi = bounds if bounds is not None else _default_radius_bounds(samples)
    if not (0 < lo < hi):
        raise HerdInputError(f'radius bounds must satisfy 0 < lo < hi (got {lo}, {hi})')
    if pairs is None or pairs.max_radius < hi:
        pairs = pair_geometry(samples.positions, samples.frame_sizes, hi * 1.0001)
    use = samples.usable
    Y = samples.targets[use]
    y2 = Y.reshape(-1)
    unsat = np.repeat(np.linalg.norm(Y, axis=1) < 0.9 * v_max, 2)
    seen = {}
    features = RadiusFeatures(pairs, samples.positions, samples.previous, policies, walls)

    def loss(r):
        if r not in seen:
            theta = features.at(r)[use]
            X = _design(theta)
            Xw = X * unsat[:, None]
            G = Xw.T @ X                         # normal equations: K×K, cheap
            cols = np.diag(G) > 0
            k = np.zeros(X.shape[1])
            if cols.any():
                k[cols] = np.linalg.lstsq(G[np.ix_(cols, cols)], (Xw.T @ y2)[cols],
                                          rcond=None)[0]
            err = saturate(np.einsum('nkd,k->nd', theta, k), v_max) - Y
            seen[r] = float(np.mean(np.sqrt(np.einsum('nd,nd->n', err, err))))
        return seen[r]

    grid = np.linspace(lo, hi, coarse)
    step = grid[1] - grid[0]
    vals = np.array([loss(r) for r in grid])
    best = float(grid[int(np.argmin(vals))])
    for _ in range(zoom_levels):
        grid = np.clip(np.linspace(best - step, best + step, zoom_points), lo, hi)
        step = 2 * step / (zoom_points - 1)
        vals = np.array([loss(r) for r in grid])
        ties = grid[vals <= vals.min() + 1e-12]
        best = float(ties[int(np.argmin(np.abs(ties - np.median(ties))))])
    radii = np.array(list(seen.keys()))
    return RadiusSearch(best, radii, np.array([seen[r] for r in radii]), (lo, hi), pairs)


@dataclass
class ImitationFit:
    """Result of :func:`learn_policy`: the policy plus diagnostics (readable with print)."""

    policy: ImitationPolicy
    mae: float
    mae_constant_velocity: float
    mae_stay_put: float
    v_max_estimate: VmaxEstimate
    radius_search: RadiusSearch
    n_samples: int
    saturated_share: float
    timings: dict = field(default_factory=dict)
    first_pass: ImitationPolicy | None = None

    def summary(self) -> str:
        """The fitted gains with their standard errors, one policy per line."""
        p = self.policy
        lines = [f'{"policy":>16s}  {"gain":>8s}  {"se":>7s}']
        for name, k, s in zip(p.policies, p.gains, p.gains_se):
            lines.append(f'{name:>16s}  {k:8.4f}  {s:7.4f}')
        lines += [f'radius r = {p.radius:.3f} m   v_max = {p.v_max:.3f} m/s '
                   f'({self.v_max_estimate.method})   dt = {p.dt:g} s',
                   f'one-step MAE {self.mae:.4f} m/s  (constant velocity '
                   f'{self.mae_constant_velocity:.4f}, stay put {self.mae_stay_put:.4f}); '
                   f'{self.n_samples} samples, {100 * self.saturated_share:.1f} % saturated']
        return '\n'.join(lines)


def learn_policy(runs: list[HerdTrajectory], policies, *, walls=None, radius=None,
                 radius_bounds=None, v_max=None, errors_in_variables: str = 'iv',
                 prune_below: float | None = None, progress=None) -> ImitationFit:
    """The full pipeline (module docstring) on trajectory runs.

    Args:
        runs: trajectories on one clock step Δt (each a separate run).
        policies: policy names to learn gains for.
        walls: enclosure (xmin, xmax, ymin, ymax) for the wall policies.
        radius: fix r instead of searching it; ``radius_bounds``: search interval (m).
        v_max: fix the speed limit instead of estimating it.
        errors_in_variables: ``'iv'`` (lagged instruments, default) or ``'none'`` (naive).
        prune_below: if set (the paper's 0.1), refit keeping policies with |k| ≥ this.
        progress: optional callable(str) told about each stage.
    """
    policies = check_policies(policies)
    walls = check_walls(walls)
    if errors_in_variables not in ('iv', 'none'):
        raise HerdInputError(f'errors_in_variables must be iv or none '
                             f'(got {errors_in_variables!r})')
    tell = progress or (lambda s: None)
    timings = {}
    t0 = time.perf_counter()
    samples = build_samples(runs)
    use = samples.usable
    Y = samples.targets[use]
    speeds = np.linalg.norm(samples.targets, axis=1)
    vest = estimate_v_max(speeds)
    vm = float(v_max) if v_max is not None else vest.v_max
    timings['prepare'] = time.perf_counter() - t0

    t0 = time.perf_counter()
    tell('radius search')
    bounds = None
    if radius is None:
        bounds = radius_bounds or _default_radius_bounds(samples)
    reach = float(radius) if radius is not None else float(bounds[1])
    pairs = pair_geometry(samples.positions, samples.frame_sizes, reach * 1.0001)
    timings['neighbour_pairs'] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if radius is None:
        rs = search_radius(samples, policies, vm, walls=walls, bounds=bounds, pairs=pairs)
        r = rs.radius
    else:
        r = float(radius)
        rs = RadiusSearch(r, np.array([r]), np.array([np.nan]), (r, r), pairs)
    timings['radius_search'] = time.perf_counter() - t0

    t0 = time.perf_counter()
    tell('gain fit')

    def fit(names, vm):
        theta_all = RadiusFeatures(pairs, samples.positions, samples.previous, names,
                                   walls).at(r)
        theta = theta_all[use]
        inst = None
        if errors_in_variables == 'iv':   # (n, L·K, 2): the features at every lag
            lagged = samples.lagged[use]
            inst = np.concatenate([theta_all[lagged[:, m]] for m in range(lagged.shape[1])],
                                  axis=1)
        gf = fit_gains(theta, Y, vm, instruments=inst, tracks=samples.track[use])
        if v_max is None:       # alternate: v_max for these gains, then the gains again
            for _ in range(2):
                vm = refine_v_max(theta, Y, gf.gains, vest.v_max)
                gf = fit_gains(theta, Y, vm, instruments=inst, tracks=samples.track[use])
        pol = ImitationPolicy(names, gf.gains, r, vm, samples.dt, gains_se=gf.gains_se,
                              walls=walls)
        return pol, theta

    policy, theta = fit(policies, vm)
    vm = policy.v_max
    first = None
    if prune_below is not None:
        keep = [p for p, k in zip(policies, policy.gains) if abs(k) >= prune_below]
        if keep and keep != policies:
            first = policy
            policy, theta = fit(keep, vm)
    timings['gain_fit'] = time.perf_counter() - t0
    pred = saturate(np.einsum('nkd,k->nd', theta, policy.gains), vm)
    sat_share = float(np.mean(np.linalg.norm(np.einsum('nkd,k->nd', theta, policy.gains),
                                             axis=1) > vm))
    return ImitationFit(policy, mae(pred, Y), mae(samples.previous[use], Y),
                        float(np.mean(np.linalg.norm(Y, axis=1))), vest, rs, int(use.sum()),
                        sat_share, timings, first)
