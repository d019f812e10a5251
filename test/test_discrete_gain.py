"""The range pull's gain on the model's clock (herd_ros.model.discrete_gain, (G1)): the spread
it means, held by the discrete loop itself (simulated), and a stable loop when the spread is
out of reach."""
import numpy as np
import pytest

from herd_ros.model.discrete_gain import discrete_gain, loop_gain, spread_factor
from herd_ros.model.herd_place import herd_place, place_coupling
from herd_ros.model.space_use_field import home_gain, range_gain


def loop_spread(a, c, dt, q, chains=4000, steps=3000, burn=1000, seed=0):
    """Var x of x' = x + Δt u, u' = a u − (c/Δt) x + w, Var w = q, over many chains."""
    rng = np.random.default_rng(seed)
    x = np.zeros(chains)
    u = np.zeros(chains)
    acc = []
    for t in range(steps):
        x, u = x + dt * u, a * u - (c / dt) * x + np.sqrt(q) * rng.standard_normal(chains)
        if t >= burn:
            acc.append(x.copy())
        if not np.isfinite(x).all() or np.abs(x).max() > 1e12:
            return np.inf
    return float(np.var(np.concatenate(acc)))


def test_small_steps_keep_the_small_step_gain():
    c0 = np.array([1e-5, 1e-4, 1e-3])
    assert loop_gain(c0, 0.5) == pytest.approx(c0, rel=5e-3)
    # and (G1) tends to (S2)'s 1/(2(1 − a) c)
    assert spread_factor(1e-6, 0.3) == pytest.approx(1 / (2 * 0.7 * 1e-6), rel=1e-5)


def test_the_gain_solves_g1_to_rounding_from_tiny_to_the_stability_edge():
    """The root is exact in relative terms however small: f(c) equals the spread asked for
    (σ²/(Δt² q κ) of (S2)) to 1e-12, for small-step gains from 1e-12 to near the edge,
    dampings from −0.9 to 0.99 and couplings 1 to 3 (a bisection on (0, best] with 60 halvings
    was off by 1e-7 at c = 1e-12)."""
    rng = np.random.default_rng(3)
    c0 = 10.0 ** rng.uniform(-12, -0.5, 400)
    a = rng.uniform(-0.9, 0.99, 400)
    for kappa in (1.0, 1.5, 3.0):
        c = loop_gain(c0, a, kappa) * kappa
        f = spread_factor(c, a)
        target = 1.0 / (2.0 * (1.0 - a) * kappa * c0)
        reached = f <= target * (1 + 1e-9)
        assert reached.sum() > 300                     # most are inside the stable range
        np.testing.assert_allclose(f[reached], target[reached], rtol=1e-12)
        # the rest sit at the minimum of f: a little more or less gain widens the spread
        rest = ~reached
        assert (spread_factor(c[rest] * 0.99, a[rest]) > f[rest]).all()
        assert (spread_factor(np.minimum(c[rest] * 1.01, 0.999 * (1 - a[rest])),
                              a[rest]) > f[rest]).all()


def test_the_loop_holds_the_spread_the_range_asks_for():
    a, dt, q, sigma2 = 0.3, 10.0, 0.02, 10.0
    c0 = dt * dt * q / (2 * (1 - a) * sigma2)            # (S2): K Δt
    assert c0 == pytest.approx(0.142857, rel=1e-4)
    c = float(loop_gain(c0, a))
    assert loop_spread(a, c, dt, q) == pytest.approx(sigma2, rel=0.04)
    # the small-step gain at this clock misses the spread by a third or more
    assert loop_spread(a, c0, dt, q) > 1.3 * sigma2


def test_a_spread_out_of_reach_gets_the_tightest_stable_loop():
    a, dt, q = -0.1, 120.0, 0.05
    sigma2 = dt * dt * q / (2 * (1 - a) * 1.4)            # the small-step c would be 1.4
    assert 1.4 > 1 - a                                    # beyond the stability edge
    assert loop_spread(a, 1.4, dt, q, steps=400, burn=0) == np.inf
    c = float(loop_gain(1.4, a))
    assert 0 < c < 1 - a
    grid = np.linspace(0.01, 1 - a - 0.01, 300)
    assert spread_factor(c, a) <= spread_factor(grid, a).min() * (1 + 1e-3)
    var = loop_spread(a, c, dt, q)
    assert var == pytest.approx(dt * dt * q * spread_factor(c, a), rel=0.05)
    assert var > sigma2                                   # as tight as it can be, no tighter


def test_places_in_a_herd_hold_their_spread_with_the_coupling():
    """Four animals, each pulled to its place (offset from the others' centroid) with the
    gain of (G1) for κ = 4/3: the offsets' variance is the range's."""
    n, a, dt, q, sigma2 = 4, 0.2, 5.0, 0.0077, 1.2
    kappa = place_coupling(n)
    assert kappa == pytest.approx(4 / 3)
    c0 = dt * dt * q / (2 * (1 - a) * sigma2)
    c = float(loop_gain(c0, a, coupling=kappa))
    rng = np.random.default_rng(1)
    chains = 2000
    x = np.zeros((chains, n))
    u = np.zeros((chains, n))
    acc = []
    for t in range(3000):
        off = x - (x.sum(axis=1, keepdims=True) - x) / (n - 1)
        x, u = x + dt * u, a * u - (c / dt) * off + np.sqrt(q) * rng.standard_normal((chains, n))
        if t >= 1000:
            acc.append(off)
    assert np.var(np.concatenate(acc)) == pytest.approx(sigma2, rel=0.05)
    # ignoring the coupling would hold the offsets too loose or too tight by more than that
    c_plain = float(loop_gain(c0, a))
    assert abs(c_plain / c - 1) > 0.1


def test_matrices_by_eigen_direction_and_zero_gains():
    cov = np.array([[[4.0, 1.0], [1.0, 2.0]], [[1.0, 0.0], [0.0, 1.0]]])
    q = np.array([[[1e-4, 2e-5], [2e-5, 3e-4]], [[0, 0], [0, 0]]])
    a = np.array([0.5, 0.5])
    k = home_gain(cov, a, q, 1.0)
    assert discrete_gain(k, a, 1.0) == pytest.approx(k, rel=1e-3)     # small steps
    assert not discrete_gain(k, a, 1.0)[1].any()                     # zero stays zero
    big = discrete_gain(k * 5e3, a, 1.0)                             # coarse: capped
    assert (np.real(np.linalg.eigvals(big[0])) < 1 - a[0]).all()


def test_ranges_and_places_are_stable_on_a_coarse_clock():
    """The duty-cycled case: 2-minute clock, negative damping, collar-inflated noise. The
    small-step gains of the live ranges put the loop beyond its edge; range_gain does not."""
    dt, a = 120.0, np.array([-0.099, 0.004])
    q = np.array([np.diag([0.052, 0.048]), np.diag([0.03, 0.057])])
    cov = np.array([[[264.0, -178.0], [-178.0, 333.0]], [[734.0, -1589.0], [-1589.0, 6411.0]]])
    small = home_gain(cov, a, q, dt)
    assert (np.real(np.linalg.eigvals(small[0])) * dt > 1 - a[0]).any()
    _, k, _ = range_gain(np.array([50, 50]), np.zeros((2, 2)), cov, a, q, dt, coupling=4 / 3)
    for i in range(2):
        assert (np.real(np.linalg.eigvals(k[i])) * dt < 1 - a[i]).all()
    # herd_place passes the coupling of its herd
    rng = np.random.default_rng(2)
    pos = np.cumsum(rng.standard_normal((200, 3, 2)), axis=0)
    m, k3, s = herd_place(pos, np.full(3, 0.5), np.repeat(np.eye(2)[None] * 1e-6, 3, 0), 1.0)
    kk = home_gain(s, np.full(3, 0.5), np.repeat(np.eye(2)[None] * 1e-6, 3, 0), 1.0)
    assert k3 == pytest.approx(kk, rel=1e-3)                 # small steps: (S2) unchanged
