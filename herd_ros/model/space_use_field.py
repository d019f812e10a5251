"""Space-use field: the environment field g_i that makes an agent's learned law spend its
time where the animal did (a Langevin movement model).

One step ahead, cross-validation seldom keeps a field (:mod:`model_selection`): at a clock of
seconds the pull of a favourite corner is far below the noise of one step. Over hours it is
what keeps a herd in its pen or range; a simulated herd without it diffuses away (a random
walk of 72 h spreads 20 penned steers over 150 m). The Langevin movement model (Brillinger,
Preisler, Ager & Kie 2001; Michelot, Gloaguen, Blackwell & Étienne 2019, *Methods Ecol.
Evol.* 10:1894) gives the field that fixes the long run exactly: a diffusion

    dp = ½ Σ ∇log π(p) dt + Σ^½ dW

has π as its stationary density. For the law of eq. 2 with damping a_i, velocity memory κ
and noise w ~ N(0, Q_i), a constant field g moves the agent by Δt·g/(1 − a_i) per step and
the noise spreads it by Δt² Q_i/(1 − a_i)² per step (the zero-frequency gains of
u = a ū + g + w, the same for every κ), so the law's positions diffuse like the equation
above with drift Δt g/(1 − a_i) and Σ = Δt² Q_i/(1 − a_i)² when

    g_i(p) = Δt / (2 (1 − a_i)) · Q_i ∇log π_i(p)                                 (S1)

(valid when π_i varies slowly over the distance the velocity stays correlated, the
overdamped limit; the same formula follows from the Boltzmann density of the underdamped
limit, a → 1, with temperature Q_i/(2(1 − a_i))).

π_i, the agent's utilization distribution, is a Gaussian kernel density of its positions
(binned, Wand 1994, *J. Comput. Graph. Stat.* 3:433; its log-gradient exact); the
bandwidth is Worton's (1989) reference bandwidth h = σ n^(−1/6) over the agent's positions
(adehabitatHR's default, ``href``), or the given one. (S1) on the bins is
projected by weighted least squares onto the RBF basis of eq. 5 (:mod:`rbf_field`) on a
grid over the visited region widened by a quarter of its extent (spacing h, at most 20
centres per axis), so the field is an ordinary
field of the model file and every consumer (predict, simulate, the controller) uses it
unchanged. Unlike the fitted field, this one is a gradient (no circulation), and it is
exact only without interactions (they change the stationary density).

An RBF sum vanishes a few σ beyond its last centre, and an agent that gets there (a noisy
step of a duty-cycled GPS herd, a high-noise regime) would never come back: a free
simulation of five collared cows at 2-min fixes put them 0.5–2 km from their ranges. So
(S1) is split in two: the pull of the Gaussian with the agent's own mean μ_i and
covariance Σ_i of positions, exact and linear everywhere,

    g_i^home(p) = −K_i (p − μ_i),   K_i = Δt / (2 (1 − a_i)) · Q_i Σ_i⁻¹              (S2)

(the Ornstein–Uhlenbeck home range of Dunn & Gipson 1977, *Biometrics* 33:85), and the
rest of (S1), (S1) − (S2), which is projected on the RBF basis. Inside the data the sum is
(S1) as before; beyond the basis the agent is pulled home as the Gaussian pulls it. (S2)
is the model file's ``space_use_home_center`` / ``space_use_home_gain``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.model.discrete_gain import discrete_gain
from herd_ros.model.rbf_field import FieldGrid, RbfBasis

#: Bins per bandwidth of the binned positions and of the evaluation grid.
BINS_PER_BANDWIDTH = 2
#: At most this many bins along an axis (coarser bins for a wide region).
MAX_BINS_PER_AXIS = 64
#: The padding of the basis beyond the visited region: this many bandwidths, and at least
#: this fraction of the region's extent (robots that wander out are pulled back in).
PAD_BANDWIDTHS = 3.0
PAD_FRACTION = 0.25
#: RBF centres per bandwidth along each axis (spacing = bandwidth / this).
CENTRES_PER_BANDWIDTH = 1.0
#: At most this many RBF centres along an axis (a finer density is smoothed by the basis).
MAX_CENTRES_PER_AXIS = 20
#: The edge of an agent's range for the edge pull of :func:`home_drift`: this Mahalanobis
#: radius (2: the ellipse holding 1 − e⁻² = 86 % of a Gaussian's positions).
HOME_RANGE_RADIUS = 2.0


@dataclass
class UtilizationDensity:
    """The kernel density π and its log-gradient at evaluation points ``points`` (E, 2):
    ``density`` (E,) (normalised to sum 1 over the points), ``log_gradient`` (E, 2)
    (1/m); ``bandwidth`` h (m)."""

    points: np.ndarray
    density: np.ndarray
    log_gradient: np.ndarray
    bandwidth: float


def reference_bandwidth(points: np.ndarray) -> float:
    """Worton's reference bandwidth h = σ n^(−1/6), σ = √((σx² + σy²)/2), for the n
    finite ``points`` (M, 2)."""
    pts = _finite_points(points)
    sigma = float(np.sqrt(0.5 * (pts[:, 0].var() + pts[:, 1].var())))
    n = float(len(pts))
    if not sigma > 0:
        raise HerdInputError('space-use field: the positions do not spread (σ = 0)')
    return sigma * max(n, 2.0) ** (-1.0 / 6.0)


def utilization_density(points: np.ndarray, bandwidth: float,
                        bounds: tuple[float, float, float, float]) -> UtilizationDensity:
    """Gaussian kernel density of ``points`` (M, 2) (σ = h) and its exact log-gradient

        ∇log π(x) = (Σ_i c_i K_h(x − x_i) x_i / Σ_i c_i K_h(x − x_i) − x) / h²

    at the bin centres of ``bounds``; the positions are first binned (c_i counts at bin
    centres x_i, bins of h/2: the binned KDE of Wand 1994). Computed with log-sum-exp, so
    the pull back towards the data is right far outside it too (where π underflows)."""
    pts = _finite_points(points)
    h = float(bandwidth)
    if not h > 0:
        raise HerdInputError(f'space-use bandwidth must be positive, got {bandwidth}')
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    samples, counts = _bin_centres(pts, (lo[0], hi[0] + 1e-9, lo[1], hi[1] + 1e-9), h)
    xmin, xmax, ymin, ymax = bounds
    b = max(h / BINS_PER_BANDWIDTH, max(xmax - xmin, ymax - ymin) / MAX_BINS_PER_AXIS)
    gx, gy = np.meshgrid(np.arange(xmin + b / 2, xmax, b), np.arange(ymin + b / 2, ymax, b))
    ev = np.column_stack([gx.ravel(), gy.ravel()])
    logc = np.log(counts)
    log_pi = np.empty(len(ev))
    grad = np.empty((len(ev), 2))
    for s0 in range(0, len(ev), 2048):
        e = ev[s0:s0 + 2048]
        d2 = ((e[:, None, :] - samples[None]) ** 2).sum(-1)
        logk = logc[None] - d2 / (2.0 * h * h)
        m = logk.max(axis=1, keepdims=True)
        k = np.exp(logk - m)
        den = k.sum(1)
        log_pi[s0:s0 + 2048] = m[:, 0] + np.log(den)
        grad[s0:s0 + 2048] = ((k @ samples) / den[:, None] - e) / (h * h)
    dens = np.exp(log_pi - log_pi.max())
    return UtilizationDensity(ev, dens / dens.sum(), grad, h)


def _bin_centres(pts, bounds, h):
    """Occupied bins of ``pts`` over ``bounds``: their centres (B, 2) and counts (B,)."""
    xmin, xmax, ymin, ymax = bounds
    b = max(h / BINS_PER_BANDWIDTH, max(xmax - xmin, ymax - ymin) / MAX_BINS_PER_AXIS)
    nx = max(int(np.ceil((xmax - xmin) / b)), 1)
    ny = max(int(np.ceil((ymax - ymin) / b)), 1)
    hist, xe, ye = np.histogram2d(pts[:, 0], pts[:, 1], bins=(nx, ny),
                                  range=((xmin, xmin + nx * b), (ymin, ymin + ny * b)))
    ix, iy = np.nonzero(hist)
    centres = np.column_stack([0.5 * (xe[ix] + xe[ix + 1]), 0.5 * (ye[iy] + ye[iy + 1])])
    return centres, hist[ix, iy]


def langevin_drift(density: UtilizationDensity, damping: float, noise_cov: np.ndarray,
                   dt: float) -> np.ndarray:
    """(S1) at the density's points: g(p) = Δt/(2(1 − a)) Q ∇log π(p), (E, 2) in m/s per
    step."""
    _check_stationary(damping)
    q = np.asarray(noise_cov, dtype=float).reshape(2, 2)
    return dt / (2.0 * (1.0 - damping)) * density.log_gradient @ q.T


def home_pull(points: np.ndarray, damping: float, noise_cov: np.ndarray,
              dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(S2): the centre μ (2,) and gain K (2, 2) of the Gaussian home pull −K (p − μ) of an
    agent with positions ``points`` (M, 2): μ their mean, K of :func:`home_gain` with Σ
    their covariance."""
    pts = _finite_points(points)
    _check_stationary(damping)
    return pts.mean(axis=0), home_gain(np.cov(pts.T), damping, noise_cov, dt)


def home_gain(cov: np.ndarray, damping, noise_cov: np.ndarray, dt: float) -> np.ndarray:
    """K = Δt/(2(1 − a)) Q Σ⁻¹ of (S2) from the covariance Σ of an agent's positions, its
    damping a < 1 and noise Q; Σ is floored at 1e-6 of its largest eigenvalue (a herd along
    a fence line keeps a finite pull across it). Vectorised: ``cov``, ``noise_cov``
    (..., 2, 2), ``damping`` (...)."""
    sigma = np.asarray(cov, dtype=float)
    w, v = np.linalg.eigh(sigma)
    if not np.all(w[..., -1] > 0):
        raise HerdInputError('space-use field: the positions do not spread (σ = 0)')
    w = np.maximum(w, 1e-6 * w[..., -1:])
    inv = np.einsum('...ik,...k,...jk->...ij', v, 1.0 / w, v)
    q = np.asarray(noise_cov, dtype=float).reshape(sigma.shape)
    scale = dt / (2.0 * (1.0 - np.asarray(damping, dtype=float)))
    return scale[..., None, None] * q @ inv


def range_gain(weight, mean, cov, damping, noise_cov, dt: float, min_samples: int = 10,
               coupling: float = 1.0):
    """(mean (N, 2), K (N, 2, 2), cov (N, 2, 2)) of a range for the edge pull: K_i of
    :func:`home_gain` for the range's covariance, made exact and stable on the clock of
    ``dt`` (:func:`~herd_ros.model.discrete_gain.discrete_gain`, (G1); ``coupling`` κ for a
    range of offsets from the others' centroid), where agent i has ``min_samples`` (its
    ``weight`` (N,)), a spread and damping −1 < a_i < 1, else 0."""
    a = np.asarray(damping, dtype=float)
    q = np.asarray(noise_cov, dtype=float)
    cov = np.asarray(cov, dtype=float)
    gain = np.zeros_like(cov)
    top = np.linalg.eigvalsh(cov)[:, -1]
    ok = ((np.asarray(weight) >= min_samples) & (np.abs(a) < 1.0) & (top > 0)
          & np.isfinite(q).all(axis=(1, 2)))
    if ok.any():
        gain[ok] = discrete_gain(home_gain(cov[ok], a[ok], q[ok], dt), a[ok], dt, coupling)
    return np.asarray(mean, dtype=float), gain, cov


def home_drift(meta: dict | None, positions: np.ndarray) -> np.ndarray | float:
    """The home pull of every agent from a model's ``meta['space_use_home']``, for positions
    (..., N, 2); 0.0 without it. Two forms:

    * (μ (N, 2), K (N, 2, 2)): (S2), −K_i (p_i − μ_i), the Gaussian home range's pull
      everywhere (the space-use field's linear part, exact with its RBF part);
    * (μ, K, Σ (N, 2, 2)): the pull at the range's edge (:func:`edge_pull`) — none inside
      the range (where the law's own terms move the agent), the gain of (S2) on the excess
      beyond it (the live estimator's: a fitted field ends at the data and its early range
      is small, so a pull to the centre would hold robots tighter than their animals while
      the range is still being discovered)."""
    home = (meta or {}).get('space_use_home')
    if home is None:
        return 0.0
    d = np.asarray(positions, dtype=float) - home[0]
    if len(home) < 3:
        return -np.einsum('nij,...nj->...ni', home[1], d)
    return edge_pull(d, home[1], home[2])


def edge_pull(d: np.ndarray, gain: np.ndarray, cov: np.ndarray,
              share: np.ndarray | None = None) -> np.ndarray:
    """−K_i d_i (1 − r₀/r_i)₊ for displacements d (..., N, 2) from the centres of ranges of
    covariance Σ_i (N, 2, 2), r_i = √(d_iᵀ Σ_i⁻¹ d_i) and r₀ = ``HOME_RANGE_RADIUS``: zero
    within the range's edge, continuous across it, the linear pull of gain K_i (N, 2, 2) on
    the excess beyond; NaN displacements give 0. A range that has not spread yet (Σ_i = 0,
    whose gain is 0) puts every displacement beyond its edge (r_i = ∞) without overflow
    warnings. With ``share`` s_i (N,): −K_i d_i max((1 − r₀/r_i)₊, s_i), the linear pull at
    s_i of its gain inside the range too (:mod:`herd_ros.control.place_match`, (M4))."""
    inv = range_inverse(cov)
    d = np.nan_to_num(np.asarray(d, dtype=float))
    k = np.asarray(gain, dtype=float)
    x, y = d[..., 0], d[..., 1]
    with np.errstate(over='ignore', invalid='ignore'):
        r = np.sqrt(np.maximum(inv[:, 0, 0] * x * x + (inv[:, 0, 1] + inv[:, 1, 0]) * x * y
                               + inv[:, 1, 1] * y * y, 1e-300))
    r = np.where(np.isnan(r), np.inf, r)
    beyond = np.clip(1.0 - HOME_RANGE_RADIUS / r, 0.0, None)
    if share is not None:
        beyond = np.maximum(beyond, np.asarray(share, dtype=float))
    return np.stack([-(k[:, 0, 0] * x + k[:, 0, 1] * y) * beyond,
                     -(k[:, 1, 0] * x + k[:, 1, 1] * y) * beyond], axis=-1)


#: inverses of the range covariances :func:`edge_pull` was last given, by the array's
#: identity (a model's ranges are fixed arrays; a law run freely asks every step)
_INVERSES: dict = {}


def range_inverse(cov: np.ndarray) -> np.ndarray:
    """Σ_i⁻¹ (N, 2, 2) of range covariances (N, 2, 2), each eigenvalue floored at 10⁻⁶ of
    its largest (a range that does not spread in one direction); remembered for the same
    array object."""
    hit = _INVERSES.get(id(cov))
    if hit is not None and hit[0] is cov:
        return hit[1]
    w, v = np.linalg.eigh(np.asarray(cov, dtype=float))
    w = np.maximum(w, 1e-6 * np.maximum(w[..., -1:], 1e-300))
    inv = np.einsum('nik,nk,njk->nij', v, 1.0 / w, v)
    if isinstance(cov, np.ndarray):
        if len(_INVERSES) >= 64:
            _INVERSES.clear()
        _INVERSES[id(cov)] = (cov, inv)
    return inv


def subset_home(meta: dict | None, index) -> dict:
    """``meta``'s home pull for the agents ``index`` (a robot fleet's animals), as a dict to
    merge into the subset model's meta (empty without it)."""
    home = (meta or {}).get('space_use_home')
    if home is None:
        return {}
    idx = np.asarray(index)
    return {'space_use_home': tuple(np.asarray(h)[idx] for h in home)}


def project_on_basis(density: UtilizationDensity, drift: np.ndarray, basis: RbfBasis,
                     ridge: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """θu, θv minimising Σ_points w (g(bin) − Σ_k θ_k φ_k(bin))², w = π + mean π (where the
    agent is, and enough everywhere in the padded region to keep the pull back in)."""
    phi = basis.features(density.points)
    w = density.density
    w = w + w.mean()
    sw = np.sqrt(w)[:, None]
    a = phi * sw
    target = drift.reshape(-1, 2) * sw
    gram = a.T @ a
    gram[np.diag_indices_from(gram)] += ridge * np.trace(gram) / len(gram)
    coef = np.linalg.solve(gram, a.T @ target)
    return coef[:, 0], coef[:, 1]


def space_use_field(positions: np.ndarray, damping: float, noise_cov: np.ndarray, dt: float,
                    bandwidth: float | None = None, bounds=None):
    """The field (S1) of one agent from its positions (T, 2) on the model clock (NaN where
    missing): returns (basis, field_u, field_v, info) with info = bandwidth, bounds and the
    home pull (S2) (``home_center`` μ, ``home_gain`` K); the RBF part is (S1) − (S2).

    ``bounds`` (xmin, xmax, ymin, ymax) of the density and basis default to the visited
    region widened by three bandwidths or a quarter of its extent, whichever is more."""
    p = np.asarray(positions, dtype=float).reshape(-1, 2)
    pts = _finite_points(p)
    if bandwidth is None:
        bandwidth = reference_bandwidth(pts)
    h = float(bandwidth)
    if bounds is None:
        pad = max(PAD_BANDWIDTHS * h, PAD_FRACTION * float((pts.max(0) - pts.min(0)).max()))
        lo, hi = pts.min(axis=0) - pad, pts.max(axis=0) + pad
        bounds = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))
    density = utilization_density(pts, h, bounds)
    mu, gain = home_pull(pts, damping, noise_cov, dt)
    # the RBF carries (S1) − (S2); the linear home pull (S2) is kept apart (exact everywhere)
    drift = langevin_drift(density, damping, noise_cov, dt) + (density.points - mu) @ gain.T
    xmin, xmax, ymin, ymax = bounds
    spacing = max(h / CENTRES_PER_BANDWIDTH,
                  max(xmax - xmin, ymax - ymin) / MAX_CENTRES_PER_AXIS)
    grid = FieldGrid(max(int(round((xmax - xmin) / spacing)), 1),
                     max(int(round((ymax - ymin) / spacing)), 1), tuple(bounds))
    basis = RbfBasis.from_grid(grid)
    fu, fv = project_on_basis(density, drift, basis)
    return basis, fu, fv, {'bandwidth': h, 'bounds': list(bounds), 'home_center': mu,
                           'home_gain': gain}


def _agent_field(model, i: int):
    """Agent i's current (basis, field_u, field_v) in either model kind."""
    if hasattr(model, 'laws'):
        law = model.laws[model.agents[i]]
        return law.basis, law.field_u, law.field_v
    return model.bases[i], model.field_u[i], model.field_v[i]


def _check_stationary(damping: float) -> None:
    if not damping < 1.0:
        raise HerdInputError(f'space-use field needs damping < 1 (a stationary law), '
                             f'got {damping:.4g}')


def _finite_points(points) -> np.ndarray:
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(-1)]
    if len(pts) < 3:
        raise HerdInputError(f'space-use field needs at least 3 positions, got {len(pts)}')
    return pts


def with_space_use_field(model, positions: np.ndarray, bandwidth: float | None = None,
                         progress=None):
    """A copy of ``model`` (pairwise :class:`HerdModel` or shared law) whose every agent's
    field g_i is the space-use field (S1) of its positions (the RBF field plus the home pull
(S2) in ``meta['space_use_home']``); ``positions`` (T, N, 2) in the
    model's agents order, on its clock (runs may be stacked; NaN where missing). The
    field's standard errors are 0 (it is not a least-squares estimate); the rest of θ_i
    and its errors are kept. ``model.meta['space_use_bandwidth']`` records h per agent; an
    agent whose field cannot be made (too few positions, damping ≥ 1) keeps its fitted
    field, and ``model.meta['space_use_kept_fitted']`` says why ({agent: reason})."""
    import dataclasses

    p = np.asarray(positions, dtype=float)
    n = len(model.agents)
    fields, bandwidths, kept = [], [], {}
    old_home = (model.meta or {}).get('space_use_home')
    centers = np.zeros((n, 2)) if old_home is None else np.array(old_home[0], dtype=float)
    gains = np.zeros((n, 2, 2)) if old_home is None else np.array(old_home[1], dtype=float)
    for i, a in enumerate(model.agents):
        try:
            basis, fu, fv, info = space_use_field(p[:, i], float(model.damping[i]),
                                                  model.noise_cov[i], model.dt, bandwidth)
            bandwidths.append(info['bandwidth'])
            centers[i], gains[i] = info['home_center'], info['home_gain']
        except HerdInputError as err:                 # too few positions, an unstable law
            basis, fu, fv = _agent_field(model, i)    # (and its home pull, if it had one)
            kept[a] = str(err)
            bandwidths.append(np.nan)
        fields.append((basis, fu, fv))
        if progress is not None:
            progress(1)
    meta = {**(model.meta or {}), 'space_use_bandwidth': np.array(bandwidths),
            'space_use_kept_fitted': kept}
    if np.any(gains):
        meta['space_use_home'] = (centers, gains)
    if hasattr(model, 'laws'):
        laws = {}
        for a, (basis, fu, fv) in zip(model.agents, fields):
            law = model.laws[a]
            se = law.theta_se
            if se is not None:
                keep = 1 + len(law.theta1) + len(law.theta2)
                se = np.concatenate([se[:keep], np.zeros(2 * basis.size)])
            laws[a] = dataclasses.replace(law, basis=basis, field_u=fu, field_v=fv, theta_se=se)
        return type(model)(agents=list(model.agents), dt=model.dt, laws=laws,
                           frame_id=model.frame_id, datum=model.datum, meta=meta)
    se = model.theta_se
    if se is not None:
        se = [np.concatenate([np.asarray(s)[:len(s) - 2 * len(model.field_u[i])],
                              np.zeros(2 * fields[i][0].size)]) for i, s in enumerate(se)]
    return dataclasses.replace(model, bases=[f[0] for f in fields],
                               field_u=[f[1] for f in fields], field_v=[f[2] for f in fields],
                               theta_se=se, meta=meta)
