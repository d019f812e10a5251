"""Compiled per-agent kernel of the herd RLS update (numba), one agent's P kept in cache.

The update of :class:`herd_ros.estimation.rls.HerdRLS` (directional forgetting + Joseph form,
module docstring of :mod:`herd_ros.estimation.rls`, steps 1–2) is memory-bound for large
herds: every agent has its own P_i (p × p, p ≈ 20–700) and the arithmetic per element of
P_i is a handful of flops. The batched numpy path reads and writes P several times and
builds p × p temporaries; this kernel walks the agents one by one and, per agent,

1. reads P_i once for M = H P (2 × p), four rows at a time (P_i then sits in the cache);
2. does the 2 × 2 algebra of forgetting and gain in scalars, in the closed forms of the
   numpy path (S₀ = M Hᵀ, S₀⁺ by its eigen-decomposition, A, S, S⁻¹, M̄ = A M, Kᵀ = S⁻¹ M̄,
   θ⁺ = θ + M̄ᵀ S⁻¹ e);
3. writes P_i once, in place, with the Joseph form of the numpy path,

       P⁺ = s P + Z C Zᵀ,   Z = [K, M̄ᵀ, Mᵀ],   C = [[S, −I, 0], [−I, 0, 0], [0, 0, W₀]],

   s = 1 or 1/λ, but with the eigen-decomposition of C in closed form: all 2 × 2 blocks
   are diagonal in the eigenbasis of S₀, so C splits into two 2 × 2 problems on
   (v_kᵀ Kᵀ, v_kᵀ M̄) and Z C Zᵀ = Σ_k ± b_k b_kᵀ with 4 rank-1 terms (the numpy path
   eigen-decomposes the 6 × 6 C: 6 terms); 4 fused multiply-adds per element of P, the
   K and M̄ terms of the Joseph form kept apart (comments in :func:`_herd_update`).
   Each product ±b_ki b_kj commutes and the sum order is fixed, so P stays symmetric to
   the last bit; no p × p temporary, O(p²) per agent.

While agent a is updated (compute-bound, P_a in cache), the P of the next agent is
prefetched, so its first pass finds it on the way from memory.

Why written by hand: no library updates a stack of independent covariance matrices in place
with a rank-k Joseph correction; BLAS offers one matrix per call (dsyrk/dger), which costs a
Python call per agent and term.

The numerics are those of the numpy path (same equations; rounding differs, ~1e-15
relative per update, ~1e-13 after 40 updates; test_rls.py checks agreement to 1e-10, and
acceptance 1, RLS = batch least squares at P₀ = 10¹⁰, holds to ~2e-8 on either path).

``numba`` is optional: :func:`compiled_update` returns None when it cannot be imported or
compiled, and :class:`HerdRLS` then uses the numpy path. Compiled code is cached on disk
(``cache=True``): in ``__pycache__`` next to this file when writable, else numba's
user-wide cache directory (``NUMBA_CACHE_DIR`` overrides both; with no writable directory
at all it compiles once per process). It is compiled (~5 s) or loaded from the cache
(~0.3 s) lazily, when the first :class:`HerdRLS` is built.
"""
from __future__ import annotations

import warnings

import numpy as np

try:
    import numba
    from llvmlite import binding as _llvm, ir as _ir
    from numba import njit, types as _types
    from numba.core import cgutils as _cgutils
    from numba.extending import intrinsic as _intrinsic
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

AVAILABLE = numba is not None

#: forgetting modes of :func:`herd_update`
NO_FORGETTING, DIRECTIONAL, EXPONENTIAL = 0, 1, 2
#: doubles per SIMD register the column split of :func:`_add_symmetric_rank` aims at
VECTOR_WIDTH = 8


def _prefetch_stub(arr, flat_index):  # pragma: no cover - replaced by the intrinsic
    pass


if AVAILABLE:
    _PREFETCH = ('llvm.prefetch.p0' if _llvm.llvm_version_info[0] >= 15
                 else 'llvm.prefetch.p0i8')

    @_intrinsic
    def _prefetch(typingctx, arr, flat_index):
        """Hint the CPU to load the cache line of ``arr.flat[flat_index]`` (C-contiguous)."""
        if not (isinstance(arr, _types.Array) and isinstance(flat_index, _types.Integer)):
            return None

        def codegen(context, builder, signature, args):
            ary = context.make_array(signature.args[0])(context, builder, args[0])
            i8p = _ir.IntType(8).as_pointer()
            i32 = _ir.IntType(32)
            fnty = _ir.FunctionType(_ir.VoidType(), [i8p, i32, i32, i32])
            fn = _cgutils.get_or_insert_function(builder.module, fnty, _PREFETCH)
            ptr = builder.bitcast(builder.gep(ary.data, [args[1]]), i8p)
            # read, locality 2 (prefetcht1: into L2, not L1, where the current agent works)
            builder.call(fn, [ptr, i32(0), i32(2), i32(1)])
            return context.get_dummy_value()
        return _types.void(arr, flat_index), codegen
else:  # pragma: no cover
    _prefetch = _prefetch_stub


def _dot(a, b):
    """Σ_j a_j b_j (compiled with reassociation: vectorized, any summation order)."""
    s = 0.0
    for j in range(a.shape[0]):
        s += a[j] * b[j]
    return s


def _zero_if_finite(a):
    """0 if every a_j is finite, else NaN (Σ 0·a_j; inf·0 = NaN)."""
    s = 0.0
    for j in range(a.shape[0]):
        s += a[j] * 0.0
    return s


def _rows_times_covariance(h, Pn, M):
    """M = H P (2 × p) for one agent, reading P once, four rows at a time."""
    p = Pn.shape[0]
    M0 = M[0]
    M1 = M[1]
    h0 = h[0]
    h1 = h[1]
    for j in range(p):
        M0[j] = 0.0
        M1[j] = 0.0
    i = 0
    while i + 3 < p:
        r0 = Pn[i]
        r1 = Pn[i + 1]
        r2 = Pn[i + 2]
        r3 = Pn[i + 3]
        a0, a1, a2, a3 = h0[i], h0[i + 1], h0[i + 2], h0[i + 3]
        c0, c1, c2, c3 = h1[i], h1[i + 1], h1[i + 2], h1[i + 3]
        for j in range(p):
            x0 = r0[j]
            x1 = r1[j]
            x2 = r2[j]
            x3 = r3[j]
            M0[j] += (a0 * x0 + a1 * x1) + (a2 * x2 + a3 * x3)
            M1[j] += (c0 * x0 + c1 * x1) + (c2 * x2 + c3 * x3)
        i += 4
    while i < p:
        r0 = Pn[i]
        a0 = h0[i]
        c0 = h1[i]
        for j in range(p):
            M0[j] += a0 * r0[j]
            M1[j] += c0 * r0[j]
        i += 1


def _add_rank_rows(Pn, B, signs, scale, row0, row1, ncols, P, nxt):
    """Rows row0..row1−1 of P ← s P + b₀b₀ᵀ ± b₁b₁ᵀ + b₂b₂ᵀ ± b₃b₃ᵀ (signs), two rows at a
    time: columns < ncols computed, columns ≥ ncols copied from the (already updated) rows
    ≥ ncols; prefetches the same rows of P[nxt] (nxt < 0: none).

    The value of an element is the same expression for (i, j) and (j, i): every product
    ±b_ki b_kj is exact before rounding and commutes (also inside a fused multiply-add), and
    the sum order is fixed.
    """
    p = Pn.shape[0]
    B0, B1, B2, B3 = B[0], B[1], B[2], B[3]
    s1 = signs[0]
    s3 = signs[1]
    i = row0
    while i < row1:
        two = i + 1 < row1
        if nxt >= 0:
            base = (nxt * p + i) * p
            for k in range(0, (2 if two else 1) * p, VECTOR_WIDTH):
                _prefetch(P, base + k)
        r = Pn[i]
        b0, b1, b2, b3 = B0[i], s1 * B1[i], B2[i], s3 * B3[i]
        if two:
            q = Pn[i + 1]
            c0, c1, c2, c3 = B0[i + 1], s1 * B1[i + 1], B2[i + 1], s3 * B3[i + 1]
            for j in range(ncols):
                x0, x1, x2, x3 = B0[j], B1[j], B2[j], B3[j]
                r[j] = r[j] * scale + ((b0 * x0 + b1 * x1) + (b2 * x2 + b3 * x3))
                q[j] = q[j] * scale + ((c0 * x0 + c1 * x1) + (c2 * x2 + c3 * x3))
            if ncols < p:
                for j in range(ncols, p):
                    r[j] = Pn[j, i]
                    q[j] = Pn[j, i + 1]
            i += 2
        else:
            for j in range(ncols):
                r[j] = r[j] * scale + ((b0 * B0[j] + b1 * B1[j]) + (b2 * B2[j] + b3 * B3[j]))
            if ncols < p:
                for j in range(ncols, p):
                    r[j] = Pn[j, i]
            i += 1


def _add_symmetric_rank(Pn, B, signs, scale, P, nxt):
    """P ← s P + b₀b₀ᵀ ± b₁b₁ᵀ + b₂b₂ᵀ ± b₃b₃ᵀ in place, P symmetric in and out.

    The columns are split at q = p − p mod 8 so that the row loops run whole SIMD vectors
    (no scalar remainder loop): the rows ≥ q are computed whole first, then the rows < q
    get columns < q computed and columns ≥ q copied from their mirror image in the rows ≥ q
    (bit-identical to computing them, see _add_rank_rows).
    """
    p = Pn.shape[0]
    q = p - p % VECTOR_WIDTH
    _add_rank_rows(Pn, B, signs, scale, q, p, p, P, nxt)
    for i in range(q, p):       # the ≤ 7 × 7 corner: symmetric whatever FMAs the compiler
        for j in range(i + 1, p):   # chose for the one- and two-row loops
            Pn[j, i] = Pn[i, j]
    _add_rank_rows(Pn, B, signs, scale, 0, q, q, P, nxt)


def _herd_update(P, theta, H, y, use, lam, mode, samples, sq_residual, weight, e_all):
    """All of :meth:`HerdRLS.update` (module docstring of rls.py, steps 1–2) in place.

    Args:
        P: (N, p, p) C-contiguous symmetric covariances, updated in place.
        theta: (N, p) estimates, updated in place.
        H: (N, 2, p) regression rows; y: (N, 2) targets.
        use: (N,) bool, agents to update; agents with a non-finite row are skipped too.
        lam: forgetting factor λ; mode: NO_FORGETTING, DIRECTIONAL or EXPONENTIAL.
        samples (N,), sq_residual (N, 2, 2), weight (N,): counters, updated for the agents
            used (samples + 1, λ Σ r rᵀ + r rᵀ with r = y − H θ⁺, λ w + 1).
        e_all: (N, 2) output, a-priori residuals y − H θ (NaN for skipped agents).
    """
    N = P.shape[0]
    p = P.shape[1]
    agents = np.empty(N, dtype=np.int64)
    n_used = 0
    for n in range(N):
        e_all[n, 0] = np.nan
        e_all[n, 1] = np.nan
        if use[n] and np.isfinite(y[n, 0] + y[n, 1] + _zero_if_finite(H[n, 0])
                                  + _zero_if_finite(H[n, 1])):
            agents[n_used] = n
            n_used += 1
    M = np.empty((2, p))     # H P
    Mb = np.empty((2, p))    # M̄ = H P̄ = A M
    Kt = np.empty((2, p))    # Kᵀ = S⁻¹ M̄
    B = np.zeros((4, p))     # P⁺ = sP + b₀b₀ᵀ ± b₁b₁ᵀ + b₂b₂ᵀ ± b₃b₃ᵀ
    signs = np.ones(2)       # signs of b₁b₁ᵀ and b₃b₃ᵀ
    c = (1.0 - lam) / lam
    scale = 1.0 / lam if mode == EXPONENTIAL else 1.0
    for a in range(n_used):
        n = agents[a]
        Pn = P[n]
        h = H[n]
        # -- 1. M = H P, one pass over P ------------------------------------------------
        _rows_times_covariance(h, Pn, M)
        s00 = _dot(M[0], h[0])
        s01 = 0.5 * (_dot(M[0], h[1]) + _dot(M[1], h[0]))   # S₀ = H P Hᵀ (symmetric)
        s11 = _dot(M[1], h[1])
        e0 = y[n, 0] - _dot(h[0], theta[n])
        e1 = y[n, 1] - _dot(h[1], theta[n])
        # -- 2. forgetting: A (H P̄ = A M), W₀ (P̄ = sP + Mᵀ W₀ M), S = H P̄ Hᵀ + I --------
        a00, a01, a10, a11 = 1.0, 0.0, 0.0, 1.0
        # eigen-decomposition of the 2 × 2 S₀ in closed form (rls._eigh2, rls._pinv2):
        # eigenvalues l₀ ≤ l₁, V = [[−sn, cs], [cs, sn]] (columns), S₀⁺ = V diag(i) Vᵀ
        m = 0.5 * (s00 + s11)
        hh = 0.5 * (s00 - s11)
        r = np.hypot(hh, s01)
        l0 = m - r
        l1 = m + r
        phi = 0.5 * np.arctan2(s01, hh)
        cs = np.cos(phi)
        sn = np.sin(phi)
        big = max(abs(l0), abs(l1))
        tol = 1e-10 * max(big, 1e-300)
        i0 = 1.0 / l0 if abs(l0) > tol else 0.0
        i1 = 1.0 / l1 if abs(l1) > tol else 0.0
        if mode == DIRECTIONAL:
            # V = [[−sn, cs], [cs, sn]] (columns: eigenvectors of l0, l1); S₀⁺ = V diag(i) Vᵀ
            q00 = sn * sn * i0 + cs * cs * i1
            q01 = -sn * cs * i0 + cs * sn * i1
            q10 = cs * -sn * i0 + sn * cs * i1
            q11 = cs * cs * i0 + sn * sn * i1
            # S₀ S₀⁺ (the projector on the range of S₀)
            t00 = s00 * q00 + s01 * q10
            t01 = s00 * q01 + s01 * q11
            t10 = s01 * q00 + s11 * q10
            t11 = s01 * q01 + s11 * q11
            a00 = 1.0 + c * t00
            a01 = c * t01
            a10 = c * t10
            a11 = 1.0 + c * t11
            # S = S₀ + c S₀ S₀⁺ S₀ + I
            u00 = t00 * s00 + t01 * s01
            u01 = t00 * s01 + t01 * s11
            u10 = t10 * s00 + t11 * s01
            u11 = t10 * s01 + t11 * s11
            S00 = s00 + c * u00 + 1.0
            S01 = s01 + c * u01
            S10 = s01 + c * u10
            S11 = s11 + c * u11 + 1.0
        elif mode == EXPONENTIAL:
            a00 = 1.0 / lam
            a11 = 1.0 / lam
            S00 = s00 / lam + 1.0
            S01 = s01 / lam
            S10 = s01 / lam
            S11 = s11 / lam + 1.0
        else:
            S00 = s00 + 1.0
            S01 = s01
            S10 = s01
            S11 = s11 + 1.0
        # S⁻¹ in closed form (rls._solve2), and the gain-weighted residual S⁻¹ e
        sb = 0.5 * (S01 + S10)
        det = S00 * S11 - sb * sb
        v00 = S11 / det
        v01 = -sb / det
        v11 = S00 / det
        g0 = v00 * e0 + v01 * e1
        g1 = v01 * e0 + v11 * e1
        # M̄ = A M, Kᵀ = S⁻¹ M̄, θ⁺ = θ + M̄ᵀ S⁻¹ e
        for j in range(p):
            mb0 = a00 * M[0, j] + a01 * M[1, j]
            mb1 = a10 * M[0, j] + a11 * M[1, j]
            Mb[0, j] = mb0
            Mb[1, j] = mb1
            Kt[0, j] = v00 * mb0 + v01 * mb1
            Kt[1, j] = v01 * mb0 + v11 * mb1
            th = theta[n, j] + (mb0 * g0 + mb1 * g1)
            theta[n, j] = th
        # standardized innovation ε = L⁻¹ e (S = L Lᵀ): Σ εᵀε is exactly the least-squares
        # residual sum of squares (λ = 1), the basis of an unbiased Q (rls.noise_cov)
        l00 = np.sqrt(S00)
        l10 = sb / l00
        l11 = np.sqrt(max(S11 - l10 * l10, 1e-300))
        f0 = e0 / l00
        f1 = (e1 - l10 * f0) / l11
        e_all[n, 0] = e0
        e_all[n, 1] = e1
        samples[n] += 1
        sq_residual[n, 0, 0] = lam * sq_residual[n, 0, 0] + f0 * f0
        sq_residual[n, 0, 1] = lam * sq_residual[n, 0, 1] + f0 * f1
        sq_residual[n, 1, 0] = lam * sq_residual[n, 1, 0] + f1 * f0
        sq_residual[n, 1, 1] = lam * sq_residual[n, 1, 1] + f1 * f1
        weight[n] = lam * weight[n] + 1.0
        # -- 3. Joseph form as Σ_k ±b_k b_kᵀ (closed-form eigen-decomposition of C) ------
        # S₀, S₀⁺, A, W₀ = c S₀⁺ and S are all diagonal in the eigenbasis V of S₀, so
        # Z C Zᵀ = K S Kᵀ − K M̄ − M̄ᵀ Kᵀ + Mᵀ W₀ M splits into the two directions v_k: with
        # z = v_kᵀ Kᵀ, m = v_kᵀ M̄ = a_k v_kᵀ M (a_k = v_kᵀ A v_k, σ_k = v_kᵀ S v_k,
        # w_k = c/l_k or 0) it is [z m] [[σ, −1], [−1, d]] [z m]ᵀ, d = w_k/a_k², whose
        # eigenvalues are μ₊ = d + t > 0 and μ₋ = d − 1/t = σ − t with
        # t = (σ − d)/2 + √(((σ − d)/2)² + 1), eigenvectors (t, −1) and (1, t):
        #   b₊ = √μ₊ (t z − m)/n,  b₋ = √|μ₋| (z + t m)/n,  n = √(t² + 1),
        # P⁺ = sP + b₊b₊ᵀ + sign(μ₋) b₋b₋ᵀ per direction: 4 rank-1 terms (d = 0 without
        # directional forgetting). The −I blocks of C keep the Joseph form's separate K and M̄.
        for k in range(2):
            if k == 0:
                v0 = -sn
                v1 = cs
                ik = i0
            else:
                v0 = cs
                v1 = sn
                ik = i1
            sig = (S00 * v0 * v0 + S11 * v1 * v1) + 2.0 * sb * v0 * v1
            d = 0.0
            if mode == DIRECTIONAL:
                ak = (a00 * v0 * v0 + a11 * v1 * v1) + (a01 + a10) * v0 * v1
                d = c * ik / (ak * ak)
            hd = 0.5 * (sig - d)
            rd = np.sqrt(hd * hd + 1.0)
            if hd >= 0.0:                     # the forms without cancellation
                t = hd + rd
                mu_minus = d - 1.0 / t
            else:
                t = 1.0 / (rd - hd)
                mu_minus = sig - t
            nrm = np.sqrt(t * t + 1.0)
            cp = np.sqrt(d + t) / nrm
            cm = np.sqrt(abs(mu_minus)) / nrm
            signs[k] = 1.0 if mu_minus >= 0.0 else -1.0
            for j in range(p):
                z = v0 * Kt[0, j] + v1 * Kt[1, j]
                mm = v0 * Mb[0, j] + v1 * Mb[1, j]
                B[2 * k, j] = cp * (t * z - mm)
                B[2 * k + 1, j] = cm * (z + t * mm)
        # prefetch the next agent's P into L2 while this one is updated
        nxt = agents[a + 1] if a + 1 < n_used else -1
        _add_symmetric_rank(Pn, B, signs, scale, P, nxt)


if AVAILABLE:
    # fastmath 'contract' only: fused multiply-adds (a product inside an FMA still commutes,
    # so P stays symmetric); no reassociation: every sum is evaluated in the order written
    def _jit(fn, fastmath=frozenset({'contract'})):
        options = {'nogil': True, 'fastmath': set(fastmath)}
        try:
            return njit(cache=True, **options)(fn)
        except RuntimeError:  # pragma: no cover - no writable cache directory at all
            return njit(**options)(fn)    # then compile once per process
    _rows_times_covariance = _jit(_rows_times_covariance)
    # dot products may be summed in any order (vectorized): rounding-level differences only
    _dot = _jit(_dot, fastmath={'contract', 'reassoc'})
    _zero_if_finite = _jit(_zero_if_finite, fastmath={'contract', 'reassoc'})
    _add_rank_rows = _jit(_add_rank_rows)
    _add_symmetric_rank = _jit(_add_symmetric_rank)
    herd_update = _jit(_herd_update)
else:  # pragma: no cover
    herd_update = None

_compiled = {}


def compiled_update():
    """:func:`herd_update` compiled (or loaded from numba's cache), or None without numba.

    Compiles on the first call with tiny arrays (the signature does not depend on the sizes);
    if that fails (numba installed but broken), warns once and returns None so that the
    caller uses the numpy path.
    """
    if 'fn' not in _compiled:
        fn = None
        if AVAILABLE:
            try:
                herd_update(np.eye(2)[None].copy(), np.zeros((1, 2)), np.ones((1, 2, 2)),
                            np.zeros((1, 2)), np.ones(1, dtype=bool), 0.5, DIRECTIONAL,
                            np.zeros(1, dtype=np.int64), np.zeros((1, 2, 2)), np.zeros(1),
                            np.empty((1, 2)))
                fn = herd_update
            except Exception as err:  # noqa: BLE001 - any failure means: use numpy
                warnings.warn(f'numba RLS kernel unavailable ({err}); using the numpy path',
                              RuntimeWarning, stacklevel=2)
        _compiled['fn'] = fn
    return _compiled['fn']
