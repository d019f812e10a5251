"""Recursive least squares for every agent of a herd at once, with directional forgetting.

Each agent i has its own linear regression (Schwager et al. 2007, eqs. 6–8): one herd
snapshot gives the x and y rows of agent i together,

    y_i = H_i θ_i + w_i,      H_i (2 × p),  y_i (2,),  θ_i (p,)

and the estimator keeps θ (N, p) and P (N, p, p) for all N agents as plain arrays. One call
of :meth:`HerdRLS.update` is one rank-2 update of every agent (no Python loop over agents):

1. **Directional forgetting** (Kulhavý & Kárný 1984; Kulhavý 1987, "Restricted exponential
   forgetting in real-time identification", Automatica 23(5):589–600; analysed by Bittanti,
   Bolzern & Campi 1990, IEEE TAC 35(12):1371–1373). Old information is forgotten *only in
   the directions the new rows excite*; in information form R = P⁻¹,

       R̄ = R − (1 − λ) Hᵀ (H P Hᵀ)⁻¹ H,

   which by the Woodbury identity is, in covariance form (never inverting P),

       S₀ = H P Hᵀ,   M = H P,   P̄ = P + ((1 − λ)/λ) Mᵀ S₀⁻¹ M.

   R̄ ≥ λR > 0, and R̄ equals R on every direction the rows do not reach, so P cannot wind
   up in an unexcited direction however long a λ < 1 estimator runs (plain exponential
   forgetting, P̄ = P/λ, grows like λ^{−t} there). Along the excited directions
   H P̄ Hᵀ = S₀/λ: the same memory 1/(1 − λ) samples as exponential forgetting.
   ``windup='exponential'`` selects plain exponential forgetting (for comparison).

2. **Measurement update** (the Kalman form of RLS with unit noise):

       S = H P̄ Hᵀ + I₂,   K = P̄ Hᵀ S⁻¹,   e = y − H θ,   θ⁺ = θ + K e,
       P⁺ = (I − K H) P̄ (I − K H)ᵀ + K Kᵀ
          = P̄ − K M̄ − M̄ᵀ Kᵀ + K (H M̄ᵀ + I) Kᵀ,   M̄ = H P̄,

   By default (``joseph=True``) it is evaluated in this Joseph form (Bucy & Joseph 1968:
   first-order insensitive to rounding errors of K), forgetting included, as one low-rank
   symmetric correction P⁺ = P(/λ) + Z C Zᵀ with Z = [K, M̄ᵀ, Mᵀ] (p × 6) and a 6 × 6 C,
   applied as Σ_k s_k b_k b_kᵀ from the eigenvectors of C: O(p²) per agent, one pass over
   P, symmetric to the last bit (no ½(P + Pᵀ) pass needed). ``joseph=False`` uses the
   algebraically equal single rank-2 correction

       P⁺ = P̄ − M̄ᵀ S⁻¹ M̄ = P + Mᵀ W M,   M̄ = A M,  W = c S₀⁺ − Aᵀ S⁻¹ A  (2 × 2),

   (A = I + c S₀ S₀⁺, c = (1 − λ)/λ), applied as Σ_k s_k b_k b_kᵀ from the eigenvectors of W,
   which is symmetric to the last bit and reads and writes P once (RLS is memory-bound
   for large herds) but is less accurate with a huge P₀ (3·10⁻⁵ vs 10⁻⁸ relative to batch
   least squares at P₀ = 10¹⁰). Agents are processed in blocks whose P fits in cache (~2 MB).
   Both forms keep P symmetric positive definite and bounded over 10⁵ steps with the
   forgetting in (1) (see test/test_rls.py).

**Two implementations of steps 1–2**, selected automatically: the compiled per-agent kernel
of :mod:`herd_ros.estimation.rls_kernels` (numba; one pass over each P_i for H P and one
for the Joseph correction, P_i in cache in between, no p × p temporaries; 8–20× faster)
when numba is importable and ``joseph=True``, else the batched numpy code of
:meth:`HerdRLS._update_block` below (also forced by ``compiled=False``). They evaluate the
same equations and agree to rounding (test_rls.py).

With λ = 1 and P₀ = p₀ I, θ after t steps is exactly the ridge solution
argmin Σ‖y − Hθ‖² + ‖θ − θ₀‖²/p₀, so a large p₀ gives the batch least-squares solution
(:mod:`herd_ros.estimation.batch_ls`); a finite p₀ is the **ridge prior** θ ~ N(θ₀, p₀ I σ²)
(``prior_mean`` θ₀, default 0). ``p0`` may be a scalar, a (p,) diagonal or an (N, p, p) array.

**Covariance of θ**: P is the covariance of θ in units of the noise variance, so
Cov θ_i ≈ σ̂_i² P_i with σ̂_i² the mean a-posteriori residual variance per component
(:meth:`HerdRLS.theta_cov`); :meth:`HerdRLS.noise_cov` is the 2 × 2 Q_i of the residuals.

**Masks**: ``update(..., mask)`` skips agents whose row is missing (an agent absent or
stale in a snapshot, a non-finite regressor); their θ, P and counters are untouched.
Non-finite rows are always masked, so a NaN never enters θ.

**Reset**: :meth:`HerdRLS.reset_covariance` sets P_i = P₀ (keeping θ_i: re-opens the
estimator after a known change); :meth:`HerdRLS.reset` also restores θ₀ and the counters.

Units: θ and P in the units of the regression (here velocities in m/s and their
regressors); λ dimensionless in (0, 1].
"""
from __future__ import annotations

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.estimation import rls_kernels

WINDUP_METHODS = ('directional', 'exponential')


def _solve2(S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """S⁻¹ B for stacks of symmetric 2×2 S (n, 2, 2) and B (n, 2, k), by the closed form."""
    a, b, d = S[:, 0, 0], 0.5 * (S[:, 0, 1] + S[:, 1, 0]), S[:, 1, 1]
    det = a * d - b * b
    inv = np.empty_like(S)
    inv[:, 0, 0] = d
    inv[:, 1, 1] = a
    inv[:, 0, 1] = inv[:, 1, 0] = -b
    inv /= det[:, None, None]
    return inv @ B


def _contiguous_t(X: np.ndarray) -> np.ndarray:
    """Xᵀ of each matrix of a stack, as a contiguous array."""
    return np.ascontiguousarray(np.swapaxes(X, 1, 2))


def _eigh2(S: np.ndarray):
    """Eigenvalues (n, 2) ascending and eigenvectors (n, 2, 2) (columns) of symmetric 2×2
    stacks, in closed form (LAPACK per 2×2 matrix costs more than the arithmetic)."""
    a, b, d = S[:, 0, 0], 0.5 * (S[:, 0, 1] + S[:, 1, 0]), S[:, 1, 1]
    m, h = 0.5 * (a + d), 0.5 * (a - d)
    r = np.hypot(h, b)
    w = np.stack([m - r, m + r], axis=1)
    # eigenvector of the larger eigenvalue: (cos φ, sin φ) with tan 2φ = 2b/(a − d)
    phi = 0.5 * np.arctan2(b, h)
    c, s = np.cos(phi), np.sin(phi)
    V = np.empty_like(S)
    V[:, 0, 1], V[:, 1, 1] = c, s
    V[:, 0, 0], V[:, 1, 0] = -s, c
    return w, V


def _pinv2(S: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """Pseudo-inverse of symmetric PSD 2×2 stacks (n, 2, 2) (rank-deficient rows allowed)."""
    w, V = _eigh2(S)
    big = np.abs(w).max(axis=1, keepdims=True)
    inv = np.where(np.abs(w) > rcond * np.maximum(big, 1e-300), 1.0 / np.where(w == 0, 1, w), 0)
    return (V * inv[:, None, :]) @ np.swapaxes(V, 1, 2)


class HerdRLS:
    """Batched RLS state of N independent agents with p parameters each.

    Attributes (plain arrays, inspect freely):
        theta: (N, p) current estimates θ_i.
        P: (N, p, p) covariance (in units of the noise variance).
        samples: (N,) number of updates each agent received.
        forgetting: λ in (0, 1].
        sq_residual: (N, 2, 2) exponentially weighted Σ ε εᵀ of standardized innovations.
        weight: (N,) the matching weight Σ λ^k (for the mean).
        compiled: use the numba kernel when available (module docstring); False = numpy.
    """

    def __init__(self, n_agents: int, n_params: int, forgetting: float = 1.0, p0=1e6,
                 prior_mean=None, windup: str = 'directional', joseph: bool = True,
                 compiled: bool = True):
        if not (0.0 < forgetting <= 1.0):
            raise HerdInputError(f'forgetting factor must be in (0, 1], got {forgetting}')
        if windup not in WINDUP_METHODS:
            raise HerdInputError(f'windup must be one of {WINDUP_METHODS}, got {windup!r}')
        if n_agents < 1 or n_params < 1:
            raise HerdInputError(f'RLS needs ≥ 1 agent and ≥ 1 parameter, got '
                                 f'{n_agents} × {n_params}')
        self.n_agents, self.n_params = int(n_agents), int(n_params)
        self.forgetting = float(forgetting)
        self.windup = windup
        self.joseph = bool(joseph)
        self.compiled = bool(compiled)
        self._all_agents = np.ones(n_agents, dtype=bool)
        self._compiled_kernel()  # compile (or load from numba's cache) now, not mid-stream
        self.P0 = self._initial_covariance(p0)
        self.prior_mean = (np.zeros((n_agents, n_params)) if prior_mean is None else
                           np.broadcast_to(np.asarray(prior_mean, float),
                                           (n_agents, n_params)).copy())
        self.reset()

    def _initial_covariance(self, p0) -> np.ndarray:
        n, p = self.n_agents, self.n_params
        p0 = np.asarray(p0, dtype=float)
        if p0.ndim == 0:
            P0 = np.broadcast_to(np.eye(p) * float(p0), (n, p, p))
        elif p0.shape == (p,):
            P0 = np.broadcast_to(np.diag(p0), (n, p, p))
        elif p0.shape in ((p, p), (n, p, p)):
            P0 = np.broadcast_to(p0, (n, p, p))
        else:
            raise HerdInputError(f'p0 must be a scalar, ({p},), ({p}, {p}) or ({n}, {p}, {p}); '
                                 f'got shape {p0.shape}')
        diag = np.diagonal(P0, axis1=-2, axis2=-1)
        if not (np.isfinite(P0).all() and (diag > 0).all()):
            raise HerdInputError('p0 must be finite and positive')
        return P0

    # -- state ---------------------------------------------------------------------------
    def reset(self, agents=None):
        """Back to the prior: θ = θ₀, P = P₀, counters zero (all agents or a mask/indices)."""
        if agents is None or not hasattr(self, 'theta'):
            self.theta = self.prior_mean.copy()
            self.P = np.array(self.P0, dtype=float)
            self.samples = np.zeros(self.n_agents, dtype=np.int64)
            self.sq_residual = np.zeros((self.n_agents, 2, 2))
            self.weight = np.zeros(self.n_agents)
            return
        self.theta[agents] = self.prior_mean[agents]
        self.P[agents] = self.P0[agents]
        self.samples[agents] = 0
        self.sq_residual[agents] = 0.0
        self.weight[agents] = 0.0

    def reset_covariance(self, agents=None):
        """P_i = P₀ (keep θ_i): re-open the estimator after a known change of the herd."""
        if agents is None:
            self.P = np.array(self.P0, dtype=float)
        else:
            self.P[agents] = self.P0[agents]

    # -- the update ----------------------------------------------------------------------
    def update(self, H: np.ndarray, y: np.ndarray, mask=None) -> np.ndarray:
        """One rank-2 update of every agent (module docstring, steps 1–2).

        Args:
            H: (N, 2, p) the x and y regression rows of each agent.
            y: (N, 2) targets (here u^{τ+1}, m/s).
            mask: (N,) bool, True = use this agent (default all); agents with non-finite
                rows are skipped regardless.
        Returns:
            e: (N, 2) a-priori residuals y − H θ (NaN for skipped agents).
        """
        H = np.ascontiguousarray(H, dtype=float)
        y = np.ascontiguousarray(y, dtype=float)
        n, p = self.n_agents, self.n_params
        if H.shape != (n, 2, p) or y.shape != (n, 2):
            raise HerdInputError(f'RLS update needs H ({n}, 2, {p}) and y ({n}, 2), got '
                                 f'{H.shape} and {y.shape}')
        if mask is not None:
            mask = np.ascontiguousarray(mask, dtype=bool)
            if mask.shape != (n,):
                raise HerdInputError(f'RLS update mask must have shape ({n},), got '
                                     f'{mask.shape}')
        kernel = self._compiled_kernel()
        if kernel is not None:
            return self._update_compiled(kernel, H, y, mask)
        use = np.isfinite(H).all(axis=(1, 2)) & np.isfinite(y).all(axis=1)
        if mask is not None:
            use &= mask
        e_all = np.full((n, 2), np.nan)
        if not use.any():
            return e_all
        idx = np.flatnonzero(use)
        chunk = self.chunk_size()
        e_used = np.empty((len(idx), 2))
        r_used = np.empty((len(idx), 2))
        for start in range(0, len(idx), chunk):  # chunks of agents sized to stay in cache
            rows = idx[start:start + chunk]
            sl = slice(start, start + len(rows)) if len(idx) == n else rows  # views if dense
            e_used[start:start + len(rows)], r_used[start:start + len(rows)] = \
                self._update_block(sl, H[sl], y[sl])
        e, r = e_used, r_used
        sel = use
        lam = self.forgetting
        self.samples[sel] += 1
        self.sq_residual[sel] = lam * self.sq_residual[sel] + r[:, :, None] * r[:, None, :]
        self.weight[sel] = lam * self.weight[sel] + 1.0
        e_all[sel] = e
        return e_all

    def _compiled_kernel(self):
        """The numba kernel (:mod:`herd_ros.estimation.rls_kernels`) if it applies, else None.

        It implements the Joseph form only (``joseph=True``, the default) and needs numba;
        ``compiled=False`` at construction forces the numpy path.
        """
        if not (self.compiled and self.joseph):
            return None
        return rls_kernels.compiled_update()

    def _update_compiled(self, kernel, H, y, mask) -> np.ndarray:
        """:meth:`update` by the compiled per-agent kernel (same equations, one pass over
        each P_i for H P and one for the Joseph correction)."""
        # the kernel is compiled for C-contiguous writeable arrays: the state arrays are made
        # so here (np.array / np.zeros); P is the one a user may replace by hand, and
        # read-only inputs would make numba compile a second version mid-stream
        if not (self.P.flags.c_contiguous and self.P.flags.writeable):
            self.P = np.array(self.P, order='C')
        if not (H.flags.writeable and y.flags.writeable):
            H, y = H.copy(), y.copy()
        e = np.empty((self.n_agents, 2))
        if self.forgetting == 1.0:
            mode = rls_kernels.NO_FORGETTING
        elif self.windup == 'directional':
            mode = rls_kernels.DIRECTIONAL
        else:
            mode = rls_kernels.EXPONENTIAL
        kernel(self.P, self.theta, H, y, self._all_agents if mask is None else mask,
               self.forgetting, mode, self.samples, self.sq_residual, self.weight, e)
        return e

    def chunk_size(self) -> int:
        """Agents per block: P of a block ≈ 2 MB, so H P and the update hit the cache."""
        return max(1, int(2 ** 21 // (8 * self.n_params ** 2)))

    def _update_block(self, sl, Hs, ys):
        """Steps 1–2 of the module docstring for the agents ``sl`` (in place), batched numpy
        (the path without numba); returns the a-priori and a-posteriori residuals."""
        P = self.P[sl]                                    # a view for slices: updated in place
        th = self.theta[sl]
        lam = self.forgetting
        Ht = np.swapaxes(Hs, 1, 2)
        M = Hs @ P                                        # (n, 2, p)  H P
        S0 = M @ Ht                                       # (n, 2, 2)  H P Hᵀ
        eye = np.eye(2)
        if lam < 1.0 and self.windup == 'directional':
            c = (1.0 - lam) / lam
            S0p = _pinv2(S0)
            A = eye + c * (S0 @ S0p)                      # H P̄ = A H P
            W0 = c * S0p                                  # P̄ = P + Mᵀ W0 M
            S = S0 + c * (S0 @ S0p @ S0) + eye            # H P̄ Hᵀ + I
        elif lam < 1.0:
            A, W0, S = eye / lam, None, S0 / lam + eye    # P̄ = P/λ
        else:
            A, W0, S = eye, 0.0, S0 + eye
        A = np.broadcast_to(A, S.shape)
        e = ys - np.einsum('nkp,np->nk', Hs, th)
        Sinv = _solve2(S, np.broadcast_to(eye, S.shape))
        Mbar = A @ M                                      # H P̄
        th = th + np.einsum('nkp,nk->np', Mbar, np.einsum('nij,nj->ni', Sinv, e))
        # (matmul operands are made contiguous: strided stacks fall off the BLAS path)
        if self.joseph:
            # Joseph form P⁺ = P̄ − K M̄ − M̄ᵀ Kᵀ + K S Kᵀ with P̄ = P(/λ) + c Mᵀ S₀⁺ M, all
            # terms at once as P(/λ) + Z C Zᵀ, Z = [K, M̄ᵀ, Mᵀ] (p × 6),
            # C = [[S, −I, 0], [−I, 0, 0], [0, 0, c S₀⁺]], applied as Σ_k s_k b_k b_kᵀ from
            # the eigenvectors of C: one pass over P, symmetric to the last bit.
            Kt = Sinv @ Mbar                              # Kᵀ = S⁻¹ H P̄
            blocks = [Kt, Mbar] + ([] if W0 is None or lam == 1.0 else [M])
            Zt = np.concatenate(blocks, axis=1)           # (n, 4 or 6, p)
            C = np.zeros((len(S), Zt.shape[1], Zt.shape[1]))
            C[:, :2, :2] = S
            C[:, :2, 2:4] = C[:, 2:4, :2] = -eye
            if Zt.shape[1] == 6:
                C[:, 4:, 4:] = W0
            w, V = np.linalg.eigh(C)
            b = np.sqrt(np.abs(w))[:, :, None] * (_contiguous_t(V) @ Zt)
            corr = _contiguous_t(np.sign(w)[:, :, None] * b) @ b
            if W0 is None:
                P *= 1.0 / lam
            P += corr
        else:
            # P⁺ = P̄ − M̄ᵀ S⁻¹ M̄ = P(/λ) + Mᵀ W M, W = W0 − Aᵀ S⁻¹ A (2 × 2): one rank-2
            # correction written as Σ_k s_k b_k b_kᵀ (eigen-decomposition of W), which is
            # symmetric to the last bit; P is updated in place.
            W = -(np.swapaxes(A, 1, 2) @ Sinv @ A)
            if W0 is not None:
                W = W + W0
            w, V = _eigh2(W)
            b = np.sqrt(np.abs(w))[:, :, None] * (np.swapaxes(V, 1, 2) @ M)
            corr = _contiguous_t(np.sign(w)[:, :, None] * b) @ b
            if W0 is None:
                P *= 1.0 / lam
            P += corr
        if not isinstance(sl, slice):
            self.P[sl] = P
        self.theta[sl] = th
        # standardized innovation ε = L⁻¹ e with S = L Lᵀ (see noise_cov)
        Ssym = 0.5 * (S + np.swapaxes(S, 1, 2))
        L = np.linalg.cholesky(Ssym)
        eps = np.linalg.solve(L, e[..., None])[..., 0]
        return e, eps

    # -- what the estimate says ----------------------------------------------------------
    def noise_cov(self) -> np.ndarray:
        """Q_i (N, 2, 2) from the standardized innovations ε_t = L_t⁻¹ e_t (S_t = L_t L_tᵀ).

        With λ = 1, Σ_t ε_tᵀ ε_t = Σ_t e_tᵀ S_t⁻¹ e_t is exactly the residual sum of squares
        of batch least squares on the same rows (the RLS cost recursion), so dividing by the
        degrees of freedom left per component, n − p/2, is the batch estimate of Q. (The
        a-posteriori residuals y − Hθ⁺ would underestimate Q by about p·ln(n/p)/n early
        on, which makes herds simulated from an online model too calm.)
        """
        w = np.maximum(self.weight - self.n_params / 2.0, 1.0)[:, None, None]
        return self.sq_residual / w

    def theta_cov(self) -> np.ndarray:
        """Cov θ_i ≈ σ̂_i² P_i (N, p, p), σ̂_i² = trace(Q_i)/2 (degrees of freedom corrected)."""
        dof = np.maximum(2.0 * self.weight - self.n_params, 1.0)
        sigma2 = np.trace(self.sq_residual, axis1=1, axis2=2) / dof
        return sigma2[:, None, None] * self.P

    def theta_se(self) -> np.ndarray:
        """Standard errors (N, p): √diag(Cov θ_i)."""
        return np.sqrt(np.clip(np.diagonal(self.theta_cov(), axis1=1, axis2=2), 0, None))

    def condition(self) -> np.ndarray:
        """Condition number of each P_i (N,) (ratio of extreme eigenvalues)."""
        w = np.linalg.eigvalsh(self.P)
        return w[:, -1] / np.maximum(w[:, 0], 1e-300)

    # -- persistence ---------------------------------------------------------------------
    def state(self) -> dict:
        """Arrays that restore this estimator exactly (see :meth:`load_state`)."""
        return {'theta': self.theta, 'P': self.P, 'samples': self.samples,
                'sq_residual': self.sq_residual, 'weight': self.weight,
                'forgetting': np.array(self.forgetting)}

    def load_state(self, state: dict):
        """Restore :meth:`state` (shapes must match this estimator)."""
        n, p = self.n_agents, self.n_params
        shapes = {'theta': (n, p), 'P': (n, p, p), 'samples': (n,),
                  'sq_residual': (n, 2, 2), 'weight': (n,)}
        for key, shape in shapes.items():
            if key not in state or np.shape(state[key]) != shape:
                raise HerdInputError(f'RLS state: {key} must have shape {shape}')
        self.theta = np.array(state['theta'], dtype=float)
        self.P = np.array(state['P'], dtype=float)
        self.samples = np.array(state['samples'], dtype=np.int64)
        self.sq_residual = np.array(state['sq_residual'], dtype=float)
        self.weight = np.array(state['weight'], dtype=float)
