"""Stop-and-go noise: the noise w_i of eq. 2 switching between regimes (a hidden Markov chain).

Penned cattle rest most of the time and move in bursts; a baboon troop forages, then
travels. With Gaussian w_i ~ N(0, Q_i) the learned law turns that into a steady slow drift:
the right variance (so the right short-term spread) but the wrong speeds — a Gaussian
velocity has std/mean of speed √(4/π − 1) ≈ 0.52, the steers' is 1.84, and robots driven by
such a law are 84 % faster on average than the steers they imitate.

A Markov-switching scale mixture (Hamilton 1989, *Econometrica* 57:357; the
resting/travelling states of movement HMMs, Morales et al. 2004, *Ecology* 85:2436) keeps
the law and changes only its noise:

    z_i^τ ∈ {1..K} a Markov chain,  P(z^{τ+1} = l | z^τ = k) = Π_i[k, l]
    w_i^τ | z_i^τ = k  ~  N(0, Q_ik)

fitted to the residuals of the learned law (w^τ = u^{τ+1} − a ū^τ − Σf − g, which the fit
already computes) by expectation–maximisation with the scaled forward–backward recursions
(Baum–Welch; Rabiner 1989, *Proc. IEEE* 77:257). A missing residual (a gap) is a missing
emission: the chain runs on through it. K ∈ {1, 2, 3} is chosen by BIC over the whole
herd (one K for all agents). The stationary mean Σ_k π_k Q_ik stays the model's Q_i, so
everything that uses only Q_i (prediction covariances, the space-use field) is unchanged.

Model file (model-level flat arrays, as ROS parameters need them): ``noise_regime_cov``
[N × K × (qxx, qxy, qyx, qyy)] and ``noise_regime_transition`` [N × K × K, row-major].
"""
from __future__ import annotations

import numpy as np

from herd_ros.errors import HerdInputError

try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is an install requirement
    def njit(*args, **kwargs):
        """numba's decorator where numba is absent: the function unchanged."""
        return (lambda f: f) if not args or not callable(args[0]) else args[0]

#: Regime counts the selection tries (1 = plain Gaussian noise).
REGIME_COUNTS = (1, 2, 3)


def noise_factors(noise_cov: np.ndarray) -> np.ndarray:
    """L with L Lᵀ = Q for (..., 2, 2) covariances (PSD; singular allowed)."""
    q = np.asarray(noise_cov, dtype=float)
    q = 0.5 * (q + np.swapaxes(q, -1, -2))
    w, v = np.linalg.eigh(q)
    if (w < -1e-9 * np.maximum(np.abs(w).max(), 1e-300)).any():
        raise HerdInputError('a noise covariance Q_i is not positive semi-definite')
    return v * np.sqrt(np.clip(w, 0, None))[..., None, :]


def check_regimes(covariances, transition, where: str = 'noise regimes'):
    """(K, 2, 2) covariances and (K, K) transition from flat or nested lists; one clear
    error if they do not fit together, a covariance is not PSD or a row does not sum to 1."""
    try:
        c = np.asarray(covariances, dtype=float).reshape(-1, 2, 2)
        k = len(c)
        t = np.asarray(transition, dtype=float).reshape(k, k)
    except (TypeError, ValueError):
        raise HerdInputError(f'{where}: noise_regime_cov needs 4 numbers per regime and '
                             f'noise_regime_transition K × K numbers') from None
    if k < 1 or not (np.isfinite(c).all() and np.isfinite(t).all()):
        raise HerdInputError(f'{where}: noise regimes must be finite numbers')
    if (t < -1e-12).any() or not np.allclose(t.sum(1), 1.0, atol=1e-6):
        raise HerdInputError(f'{where}: every row of noise_regime_transition must be '
                             f'probabilities summing to 1')
    sym = 0.5 * (c + np.swapaxes(c, 1, 2))
    if (np.linalg.eigvalsh(sym)[:, 0] < -1e-12 * max(np.abs(sym).max(), 1e-300)).any():
        raise HerdInputError(f'{where}: a regime covariance is not positive semi-definite')
    return sym, np.clip(t, 0.0, None) / np.clip(t, 0.0, None).sum(1, keepdims=True)


def stationary_distribution(transition: np.ndarray) -> np.ndarray:
    """π with π Π = π (the left eigenvector of eigenvalue 1, normalised); a stack of
    transitions (..., K, K) gives a stack (..., K)."""
    t = np.asarray(transition, dtype=float)
    w, v = np.linalg.eig(np.swapaxes(t, -1, -2))
    one = np.argmin(np.abs(w - 1.0), axis=-1)
    pi = np.abs(np.real(np.take_along_axis(v, one[..., None, None], axis=-1)[..., 0]))
    return pi / pi.sum(axis=-1, keepdims=True)


def stationary_mean(covariances, transition) -> np.ndarray:
    """Σ_k π_ik Q_ik per agent: the stationary mean (N, 2, 2) of regime covariances
    (N, K, 2, 2) under transitions (N, K, K) — the noise level a chain keeps on average."""
    pi = stationary_distribution(transition)
    return np.einsum('nk,nkij->nij', pi, np.asarray(covariances, dtype=float))


def fit_regimes(residuals: np.ndarray, n_regimes: int, iterations: int = 200,
                tol: float = 1e-6) -> dict:
    """Baum–Welch for one agent: residuals (T, 2) (NaN = missing) -> {covariances (K, 2, 2),
    transition (K, K), initial (K,), log_likelihood, n_parameters, n_samples}.

    Started from the quantiles of ‖w‖² (regime k = the k-th slice, slowest first); regimes
    stay sorted by their variance."""
    r = np.asarray(residuals, dtype=float).reshape(-1, 2)
    ok = np.isfinite(r).all(-1)
    n = int(ok.sum())
    k = int(n_regimes)
    if n < 10 * k:
        raise HerdInputError(f'noise regimes: {n} residuals are too few for {k} regimes')
    r0 = np.where(ok[:, None], r, 0.0)
    power = (r[ok] ** 2).sum(-1)
    if not power.mean() > 0:
        raise HerdInputError('noise regimes: the residuals are all zero (an agent that never '
                             'moved)')
    edges = np.quantile(power, np.linspace(0, 1, k + 1))
    cov = np.empty((k, 2, 2))
    for j in range(k):
        sel = r[ok][(power >= edges[j]) & (power <= edges[j + 1])]
        cov[j] = sel.T @ sel / max(len(sel), 1) + 1e-12 * np.eye(2)
    trans = np.full((k, k), 0.1 / max(k - 1, 1)) if k > 1 else np.ones((1, 1))
    if k > 1:
        np.fill_diagonal(trans, 0.9)
    init = np.full(k, 1.0 / k)
    floor = 1e-9 * power.mean() * np.eye(2)
    last = -np.inf
    okf = ok.astype(np.float64)
    for _ in range(iterations):
        cov, trans_new, init, loglik = _em_step(r0, okf, cov, trans, init)
        cov = cov + floor
        if k > 1:
            trans = trans_new
        if loglik - last < tol * abs(loglik):
            break
        last = loglik
    order = np.argsort(np.trace(cov, axis1=1, axis2=2))
    cov, trans, init = cov[order], trans[np.ix_(order, order)], init[order]
    return {'covariances': cov, 'transition': trans, 'initial': init,
            'log_likelihood': float(loglik), 'n_samples': n,
            'n_parameters': 3 * k + k * (k - 1)}


def fit_herd_regimes(residuals: np.ndarray, counts=REGIME_COUNTS, margin: float = 0.0
                     ) -> dict:
    """One K for the herd by BIC (−2 log L + p log n summed over agents), residuals
    (T, N, 2) -> {'n_regimes': K, 'bic': {K: value}, 'agents': [fit_regimes per agent],
    'too_few': [indices of agents with too few residuals]}. With a ``margin``, a K larger
    than the one chosen so far is taken only when it lowers the BIC by more than the
    margin (10: "very strong" evidence, Kass & Raftery 1995, JASA 90:773).

    An agent with too few residuals for K regimes (fewer than 10 K) gets K copies of its
    residuals' covariance (Gaussian noise in K regimes' clothing) and adds nothing to the
    BIC; the herd needs at least one agent that can be fitted."""
    r = np.asarray(residuals, dtype=float)
    fits, bic, too_few = {}, {}, {}
    for k in counts:
        per, short = [], []
        for i in range(r.shape[1]):
            try:
                per.append(fit_regimes(r[:, i], k))
            except HerdInputError:
                per.append(_flat_regimes(r[:, i], k))
                short.append(i)
        if len(short) == r.shape[1]:
            continue
        fits[k], too_few[k] = per, short
        bic[k] = float(sum(-2.0 * f['log_likelihood'] + f['n_parameters'] * np.log(f['n_samples'])
                           for f in per if f['n_samples']))
    if not bic:
        raise HerdInputError('noise regimes: too few residuals to fit any regime')
    best = min(bic)
    for k in sorted(bic):
        if bic[k] < bic[best] - margin:
            best = k
    return {'n_regimes': best, 'bic': bic, 'agents': fits[best], 'too_few': too_few[best]}


def _flat_regimes(residuals: np.ndarray, k: int) -> dict:
    """K identical regimes (the residuals' covariance, 0 without residuals), uniform
    transitions: Gaussian noise, for an agent with too few residuals to fit."""
    r = residuals[np.isfinite(residuals).all(-1)]
    cov = r.T @ r / len(r) if len(r) else np.zeros((2, 2))
    return {'covariances': np.repeat(cov[None], k, axis=0), 'transition': np.full((k, k), 1 / k),
            'initial': np.full(k, 1 / k), 'log_likelihood': 0.0, 'n_samples': 0,
            'n_parameters': 0}


class RegimeNoise:
    """Draws w of R agents whose noise switches regime: covariances (R, K, 2, 2),
    transition (R, K, K); the state starts from the stationary distribution.

    ``draw(fraction)`` advances the chains by a fraction β ∈ (0, 1] of a model step
    (transition (1 − β) I + β Π, which keeps the mean dwell time in model steps) and
    returns √β L_z ξ, the noise of that fraction (L_z L_zᵀ = Q_z).
    """

    def __init__(self, covariances: np.ndarray, transition: np.ndarray, rng=None):
        self.cov = np.asarray(covariances, dtype=float)
        self.transition = np.asarray(transition, dtype=float)
        k = self.cov.shape[1]
        self.factor = noise_factors(self.cov)                              # (R, K, 2, 2)
        self.rng = np.random.default_rng(rng)
        self.state = np.array([self.rng.choice(k, p=stationary_distribution(t))
                               for t in self.transition], dtype=np.int64)

    def draw(self, fraction: float = 1.0) -> np.ndarray:
        """w of every agent for a fraction β of a model step (class docstring)."""
        beta = float(fraction)
        k = self.transition.shape[-1]
        probs = self.transition[np.arange(len(self.state)), self.state]     # (R, K)
        if beta < 1.0:
            probs = beta * probs + (1.0 - beta) * np.eye(k)[self.state]
        cum = np.cumsum(probs, axis=1)
        u = self.rng.random(len(self.state))[:, None]
        self.state = np.minimum((u > cum).sum(1), k - 1)
        xi = self.rng.standard_normal((len(self.state), 2))
        f = self.factor[np.arange(len(self.state)), self.state]            # (R, 2, 2)
        return np.sqrt(beta) * np.einsum('rij,rj->ri', f, xi)


def carry_regime_state(previous, source) -> bool:
    """Give ``source`` (a new :class:`RegimeNoise`) the regime states of ``previous`` (the
    one it replaces) when both switch regimes over the same agents and regime count, so a
    rest or a move outlives a model update; whether it did."""
    if not (isinstance(previous, RegimeNoise) and isinstance(source, RegimeNoise)):
        return False
    if previous.state.shape != source.state.shape or \
            previous.transition.shape != source.transition.shape:
        return False
    source.state = previous.state.copy()
    return True


class GaussianNoise:
    """Draws w ~ N(0, Q_i) for R agents (the paper's noise), the interface of
    :class:`RegimeNoise`: ``draw(fraction)`` returns √β L_i ξ."""

    def __init__(self, noise_cov: np.ndarray, rng=None):
        self.factor = noise_factors(noise_cov)
        self.rng = np.random.default_rng(rng)

    def draw(self, fraction: float = 1.0) -> np.ndarray:
        """w ~ N(0, β Q_i) of every agent for a fraction β of a model step."""
        xi = self.rng.standard_normal((len(self.factor), 2))
        return np.sqrt(float(fraction)) * np.einsum('rij,rj->ri', self.factor, xi)

    def draw_steps(self, steps: int) -> np.ndarray:
        """w of every agent for ``steps`` whole model steps (steps, R, 2): the draws of
        ``steps`` calls of :meth:`draw` in one (the generator's stream is the same)."""
        xi = self.rng.standard_normal((int(steps), len(self.factor), 2))
        return np.einsum('rij,krj->kri', self.factor, xi)


def noise_for(model, rng=None, scale: float = 1.0):
    """The noise source of a model: :class:`RegimeNoise` when its ``meta`` holds
    ``noise_regimes`` (covariances, transition), else :class:`GaussianNoise` from Q_i;
    ``scale`` and, per agent, ``meta['noise_scale']`` (the free-run calibration of
    :mod:`herd_ros.simulation.pace_calibration`) multiply the noise's standard deviation."""
    meta = getattr(model, 'meta', None) or {}
    regimes = meta.get('noise_regimes')
    factor = float(scale) ** 2 * np.ones(len(model.agents))
    if meta.get('noise_scale') is not None:
        factor = factor * np.asarray(meta['noise_scale'], dtype=float) ** 2
    if regimes is None:
        return GaussianNoise(np.asarray(model.noise_cov) * factor[:, None, None], rng)
    cov, trans = regimes
    return RegimeNoise(np.asarray(cov) * factor[:, None, None, None], trans, rng)


def subset_regimes(meta: dict, index) -> dict:
    """``meta``'s ``noise_regimes`` and ``noise_scale`` for the agents ``index`` (a robot
    fleet's animals), as a dict to merge into the subset model's meta (empty without
    them)."""
    meta = meta or {}
    idx = np.asarray(index)
    out = {}
    if meta.get('noise_scale') is not None:
        out['noise_scale'] = np.asarray(meta['noise_scale'], dtype=float)[idx]
    regimes = meta.get('noise_regimes')
    if regimes is not None:
        out['noise_regimes'] = (np.asarray(regimes[0])[idx], np.asarray(regimes[1])[idx])
    return out


@njit(cache=True, nogil=True, error_model='numpy')
def _em_step(r, ok, cov, trans, init):  # pragma: no cover - compiled
    """One Baum–Welch iteration (Rabiner 1989; scaled forward–backward): r (T, 2) residuals
    (0 where missing), ok (T,) 1/0, cov (K, 2, 2), trans (K, K), init (K,) -> (new cov, new
    trans, new init, log L of the given parameters). A missing residual has emission 1.
    Compiled with numpy's division (a degenerate regime gives inf/NaN and a NaN log L, as
    uncompiled, which the BIC then passes over; Python's raised ZeroDivisionError on
    residuals that are all zero, a collar that never moved)."""
    t_len = r.shape[0]
    k = cov.shape[0]
    inv = np.empty((k, 3))
    lognorm = np.empty(k)
    for j in range(k):
        a, b, d = cov[j, 0, 0], 0.5 * (cov[j, 0, 1] + cov[j, 1, 0]), cov[j, 1, 1]
        det = a * d - b * b
        inv[j, 0], inv[j, 1], inv[j, 2] = d / det, -b / det, a / det
        lognorm[j] = -np.log(2.0 * np.pi) - 0.5 * np.log(det)
    em = np.empty((t_len, k))
    shift = np.empty(t_len)
    for t in range(t_len):
        m = -np.inf
        for j in range(k):
            if ok[t] > 0.0:
                x, y = r[t, 0], r[t, 1]
                v = lognorm[j] - 0.5 * (inv[j, 0] * x * x + 2.0 * inv[j, 1] * x * y
                                        + inv[j, 2] * y * y)
            else:
                v = 0.0
            em[t, j] = v
            if v > m:
                m = v
        shift[t] = m
        for j in range(k):
            em[t, j] = np.exp(em[t, j] - m)
    alpha = np.empty((t_len, k))
    loglik = 0.0
    for t in range(t_len):
        s = 0.0
        for j in range(k):
            if t == 0:
                acc = init[j]
            else:
                acc = 0.0
                for i in range(k):
                    acc += alpha[t - 1, i] * trans[i, j]
            alpha[t, j] = acc * em[t, j]
            s += alpha[t, j]
        for j in range(k):
            alpha[t, j] /= s
        loglik += np.log(s) + shift[t]
    beta = np.ones(k)
    nxt = np.empty(k)
    xi = np.zeros((k, k))
    wsum = np.zeros(k)
    rr = np.zeros((k, 3))
    new_init = np.empty(k)
    for t in range(t_len - 1, -1, -1):
        if t < t_len - 1:
            norm = 0.0
            for i in range(k):
                for j in range(k):
                    norm += alpha[t, i] * trans[i, j] * em[t + 1, j] * nxt[j]
            for i in range(k):
                for j in range(k):
                    xi[i, j] += alpha[t, i] * trans[i, j] * em[t + 1, j] * nxt[j] / norm
            s = 0.0
            for i in range(k):
                acc = 0.0
                for j in range(k):
                    acc += trans[i, j] * em[t + 1, j] * nxt[j]
                beta[i] = acc
                s += acc
            for i in range(k):
                beta[i] /= s
        g = 0.0
        for j in range(k):
            g += alpha[t, j] * beta[j]
        for j in range(k):
            gamma = alpha[t, j] * beta[j] / g
            if t == 0:
                new_init[j] = gamma
            if ok[t] > 0.0:
                wsum[j] += gamma
                rr[j, 0] += gamma * r[t, 0] * r[t, 0]
                rr[j, 1] += gamma * r[t, 0] * r[t, 1]
                rr[j, 2] += gamma * r[t, 1] * r[t, 1]
        for j in range(k):
            nxt[j] = beta[j]
    new_cov = np.empty((k, 2, 2))
    new_trans = np.empty((k, k))
    for j in range(k):
        w = max(wsum[j], 1e-300)
        new_cov[j, 0, 0] = rr[j, 0] / w
        new_cov[j, 0, 1] = rr[j, 1] / w
        new_cov[j, 1, 0] = rr[j, 1] / w
        new_cov[j, 1, 1] = rr[j, 2] / w
        row = 0.0
        for i in range(k):
            row += xi[j, i]
        for i in range(k):
            new_trans[j, i] = xi[j, i] / max(row, 1e-300)
    return new_cov, new_trans, new_init, loglik


def regimes_scaled_to(covariances, transition, noise_cov):
    """Regime covariances rescaled per agent so that the trace of their stationary mean
    Σ_k π_ik Q_ik is tr Q_i (``noise_cov`` (N, 2, 2)); an agent with tr Q_i = 0 or no
    regime variance gets K copies of Q_i (Gaussian noise, as the model has it)."""
    cov = np.array(covariances, dtype=float, copy=True)
    trans = np.asarray(transition, dtype=float)
    q = np.asarray(noise_cov, dtype=float)
    means = stationary_mean(cov, trans)
    for i in range(len(cov)):
        target, have = float(np.trace(q[i])), float(np.trace(means[i]))
        if target > 0 and have > 0 and np.isfinite(have):
            cov[i] *= target / have
        else:
            cov[i] = q[i]
    return cov


def with_noise_regimes(model, runs_positions: list, counts=REGIME_COUNTS) -> tuple:
    """``model`` with noise regimes fitted to its residuals on ``runs_positions`` (a list of
    (T, N, 2) arrays in the model's agents order): (model, fit summary). K = 1 (BIC keeps
    plain Gaussian noise) returns the model unchanged. The regime covariances are rescaled
    so that the trace of their stationary mean is the model's tr Q_i."""
    import dataclasses

    gap = np.full((1, model.n_agents, 2), np.nan)
    parts = []
    for p in runs_positions:
        if len(p) >= 3:
            parts += [model.residuals(p), gap]
    if not parts:
        raise HerdInputError('noise regimes: no run has three steps')
    fit = fit_herd_regimes(np.concatenate(parts), counts)
    if fit['n_regimes'] == 1:
        return model, fit
    cov = np.stack([f['covariances'] for f in fit['agents']])
    trans = np.stack([f['transition'] for f in fit['agents']])
    cov = regimes_scaled_to(cov, trans, model.noise_cov)
    for i in fit['too_few']:
        cov[i] = model.noise_cov[i]                   # Gaussian noise, as the model has it
    meta = {**(model.meta or {}), 'noise_regimes': (cov, trans)}
    return dataclasses.replace(model, meta=meta), fit
