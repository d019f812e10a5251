"""The gain of a range pull on the model's clock: the spread it is meant to hold, and a loop
that stays stable however coarse the clock.

The range gain K = Δt/(2(1 − a)) Q Σ⁻¹ of (S2) (:mod:`herd_ros.model.space_use_field`) is
the small-step limit. On the model's clock the law with a pull of gain k along one of K's
eigen-directions is, for the displacement x from the range's centre,

    x^{τ+1} = x^τ + Δt u^τ,    u^{τ+1} = a u^τ − k x^τ + w^τ,    Var w = q

an AR(2) in x, x^{τ+2} = (1 + a) x^{τ+1} − (a + c) x^τ + Δt w^τ with c = k Δt, stationary
only for 0 < c < 1 − a (−1 < a < 1), with variance (Box & Jenkins; Brockwell & Davis 1991,
§3.3)

    Var x = Δt² q · f(c),   f(c) = (1 + a + c) / ((1 − a − c) · c · (2 + 2a + c))       (G1)

f(c) ≈ 1/(2(1 − a) c) for small c, which is (S2). f falls from ∞ to a minimum and rises
to ∞ again at the stability edge c = 1 − a. The gain that holds a spread σ² is the root of
f(c) = σ²/(Δt² q) on the falling branch; where σ² is below the minimum (noise too large for
the range at this clock: a duty-cycled GPS herd learned at 2 minutes, whose inflated Q made
the small-step gain put c = 1.4 beyond its stability edge 1.1, and a free simulation run
to 10³⁷ m), the gain of the minimum — the tightest spread the loop can hold, and stable.

A pull on an animal's offset from the others' centroid (its place in the herd) acts on
every animal of the herd: the offset's own gain is κ = N/(N − 1) times each animal's (the
others are pulled too), and the noise driving it κ times each animal's. ``coupling`` κ
solves (G1) for the offset and returns each animal's gain.

Plain numpy; no ROS.
"""
from __future__ import annotations

import numpy as np

#: the most steps to the root of (G1) (a bisection halves the bracket; Newton's steps
#: converge in a few)
_STEPS = 60
#: points of the grid that brackets the minimum of f
_GRID = 512


def spread_factor(c, damping):
    """f(c) of (G1) (Var x / (Δt² q)) for c = k Δt in (0, 1 − a); ∞ outside it."""
    c = np.asarray(c, dtype=float)
    a = np.asarray(damping, dtype=float)
    with np.errstate(divide='ignore', invalid='ignore'):
        f = (1.0 + a + c) / ((1.0 - a - c) * c * (2.0 + 2.0 * a + c))
    return np.where((c > 0) & (c < 1.0 - a) & (a > -1.0), f, np.inf)


def loop_gain(c_small, damping, coupling=1.0):
    """c = k Δt whose loop holds the spread that the small-step gain ``c_small`` (c of (S2),
    any shape) means, for dampings ``damping`` (broadcast): the root of (G1) on its stable
    branch, or the minimum of f where the spread is out of reach; 0 where ``c_small`` is 0
    or −1 < a < 1 fails."""
    c0 = np.asarray(c_small, dtype=float)
    a = np.broadcast_to(np.asarray(damping, dtype=float), c0.shape)
    kappa = float(coupling)
    ok = (c0 > 0) & np.isfinite(c0) & (a > -1.0) & (a < 1.0)
    out = np.zeros(c0.shape)
    if not ok.any():
        return out
    c0, a = c0[ok], a[ok]
    target = 1.0 / (2.0 * (1.0 - a) * kappa * c0)        # σ² / (Δt² q κ), from (S2)
    edge = 1.0 - a
    grid = edge[:, None] * (np.arange(1, _GRID) / _GRID)[None]
    f = spread_factor(grid, a[:, None])
    lowest = (np.arange(len(a)), np.argmin(f, axis=1))
    best = grid[lowest]                                        # the minimum of f
    reachable = f[lowest] <= target
    c_offset = best.copy()
    if reachable.any():
        r = reachable
        c_offset[r] = _falling_root(a[r], edge[r], best[r], target[r])
    out[ok] = c_offset / kappa
    return out


def _falling_root(a, edge, best, target):
    """The root of f(c) = ``target`` on (0, ``best``], where (G1)'s f falls (convex there)
    from ∞ to its minimum at ``best`` (f(best) ≤ ``target``): Newton's method kept inside a
    bracket that shrinks every step, a bisection wherever a Newton step would leave it
    (Press et al., *Numerical Recipes*, 3rd ed., §9.4, ``rtsafe``), to a few ulps. It
    starts from the small-step root 1/(2(1 − a) target) of (S2), where f is above the
    target (f(c) > 1/(2(1 − a) c) for every c in (0, 1 − a)), so Newton's steps climb to
    the root from below."""
    one_a, two_a = 1.0 + a, 2.0 + 2.0 * a
    lo, hi = np.zeros_like(best), best.copy()
    small = 1.0 / (2.0 * edge * target)
    c = np.where(small < best, small, 0.5 * best)
    with np.errstate(divide='ignore', invalid='ignore'):     # f' = 0 at the minimum
        for _ in range(_STEPS):
            # f = N / D, f' = (D − N D') / D², N = 1 + a + c, D = (1 − a − c) c (2 + 2a + c)
            n, left, right = one_a + c, edge - c, two_a + c
            d = left * c * right
            f = n / d
            slope = (d - n * (left * right - c * right + left * c)) / (d * d)
            above = f > target
            lo = np.where(above, c, lo)
            hi = np.where(above, hi, c)
            newton = c - (f - target) / slope
            inside = np.isfinite(newton) & (newton >= lo) & (newton <= hi)
            step = np.where(inside, newton, 0.5 * (lo + hi))
            done = np.abs(step - c) <= 4.0 * np.spacing(c)
            c = step
            if done.all():
                break
    return c


def discrete_gain(gain, damping, dt: float, coupling=1.0):
    """The gains (N, 2, 2) of (S2) made exact on the clock of step ``dt`` by (G1), per
    eigen-direction of each K_i (real and non-negative: K = s Q Σ⁻¹ is similar to the
    symmetric s Σ^-½ Q Σ^-½); dampings (N,). A zero gain stays zero."""
    k = np.asarray(gain, dtype=float)
    out = np.zeros_like(k)
    a = np.asarray(damping, dtype=float).reshape(-1)
    live = np.abs(k).sum(axis=(1, 2)) > 0
    if not live.any():
        return out
    lam, vec = np.linalg.eig(k[live])
    lam, vec = np.real(lam), np.real(vec)
    c = loop_gain(np.clip(lam, 0.0, None) * dt, a[live][:, None], coupling) / dt
    out[live] = np.einsum('nij,nj,njk->nik', vec, c, np.linalg.inv(vec))
    return out
