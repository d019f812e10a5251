"""The live place match (:mod:`herd_ros.control.place_match`): robots whose places spread
far wider than their animals' are brought to their animals' spread in closed loop; robots
that the law already holds tighter keep the edge pull alone; the pull inside the range is
the share of its linear part (by hand)."""
import numpy as np

from herd_ros.control.place_match import PlaceMatch, place_r2, stable_shares
from herd_ros.model.herd_place import place_offsets
from herd_ros.model.space_use_field import edge_pull


def test_the_share_adds_the_linear_pull_inside_the_range_by_hand():
    # a range of std 1 m per axis (r₀ = 2): 1 m east is inside; gain 0.1 per step
    gain = np.array([0.1 * np.eye(2)])
    cov = np.array([np.eye(2)])
    d = np.array([[1.0, 0.0]])
    np.testing.assert_allclose(edge_pull(d, gain, cov), [[0.0, 0.0]])
    np.testing.assert_allclose(edge_pull(d, gain, cov, np.array([0.3])), [[-0.03, 0.0]])
    # 4 m east: beyond the edge by half (1 − 2/4); a share below that changes nothing,
    # a share of 2 doubles the linear pull
    d = np.array([[4.0, 0.0]])
    np.testing.assert_allclose(edge_pull(d, gain, cov, np.array([0.3])), [[-0.2, 0.0]])
    np.testing.assert_allclose(edge_pull(d, gain, cov, np.array([2.0])), [[-0.8, 0.0]])
    # r² of a 3-4-5 offset in a range of std 5 m per axis
    assert abs(place_r2([[3.0, 4.0]], [[0.0, 0.0]], [25.0 * np.eye(2)])[0] - 1.0) < 1e-12


def test_shares_move_by_the_ratio_of_spreads_and_stay_in_bounds():
    m = PlaceMatch(3, memory=1e9, min_samples=4, update_every=4)
    cov = np.tile(np.eye(2), (3, 1, 1))
    mean = np.zeros((3, 2))
    animal = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]])
    # robot 0 twice as far out as its animal (r² 4 ×: a miss of ½ log 4 = log 2), robot 1
    # as far, robot 2 half as far
    robot = np.array([[2.0, 0.0], [0.0, 1.0], [0.5, 0.0]])
    changed = [m.observe(k, animal, robot, mean, cov) for k in range(4)]
    assert changed == [False, False, False, True]
    np.testing.assert_allclose(m.shares, [0.5 * np.log(2.0), 0.0, 0.0])
    for k in range(4, 400):
        m.observe(k, animal, robot, mean, cov)
    np.testing.assert_allclose(m.shares, [4.0, 0.0, 0.0])       # the upper bound
    # a tick without the animal, or a place that has not spread, is no sample
    n = m.samples.copy()
    m.observe(400, np.full((3, 2), np.nan), robot, mean, cov)
    m.observe(401, animal, robot, mean, np.zeros((3, 2, 2)))
    np.testing.assert_array_equal(m.samples, n)


def closed_loop(robot_noise, n_ticks=6000, seed=0):
    """Three animals whose offsets from the others' centroid are held by the full linear
    pull of gain K (an Ornstein-Uhlenbeck process of covariance S about their places m),
    and three robots on the same places with ``robot_noise`` × the animals' noise and the
    edge pull plus the matched share; returns the match and the last 2 000 ticks' mean r²
    (animals, robots)."""
    rng = np.random.default_rng(seed)
    n = 3
    m = np.array([[-20.0, 0.0], [20.0, 0.0], [0.0, 30.0]])
    q = 1.0                                     # noise variance per axis per tick
    k = 0.02                                    # animals' pull per tick
    # a range of the offsets' order (half their spread: the match compares the robots
    # with the animals in the same range, whatever it is)
    s = n / (n - 1.0) * q / (2.0 * k)
    cov = np.tile(s * np.eye(2), (n, 1, 1))
    gain = np.tile(k * np.eye(2), (n, 1, 1))
    match = PlaceMatch(n)
    pa = m.copy()
    pr = m.copy()
    ra, rr = [], []
    for t in range(n_ticks):
        da = place_offsets(pa) - m
        dr = place_offsets(pr) - m
        match.observe(float(t), da + m, dr + m, m, cov)
        pa = pa - (gain @ da[..., None])[..., 0] + np.sqrt(q) * rng.normal(size=(n, 2))
        pr = pr + edge_pull(dr, gain, cov, match.shares) \
            + np.sqrt(q) * np.asarray(robot_noise)[:, None] * rng.normal(size=(n, 2))
        if t >= n_ticks - 2000:
            ra.append(place_r2(da + m, m, cov))
            rr.append(place_r2(dr + m, m, cov))
    return match, np.mean(ra, axis=0), np.mean(rr, axis=0)


def test_robots_that_stray_are_brought_to_their_animals_spread():
    match, ra, rr = closed_loop([1.0, 1.0, 1.0])
    # with the edge pull alone the robots' offsets spread far wider (a pull beyond the
    # range's edge only); matched, each robot's mean r² comes within 30 % of its animal's
    assert (match.shares > 0.3).all()
    np.testing.assert_allclose(rr / ra, 1.0, atol=0.3)


def test_robots_held_tighter_by_their_law_keep_the_edge_pull_alone():
    # robots with a tenth of the noise: their law alone holds them tighter than their
    # animals, and the match leaves the pull at the range's edge (share 0)
    match, ra, rr = closed_loop([0.1, 0.1, 0.1], n_ticks=1500)
    assert (rr < ra).all()
    np.testing.assert_array_equal(match.shares, 0.0)


def test_a_share_never_makes_the_place_loop_ring():
    # (M5) by hand: a = −0.1, K = 0.0032 I per s, Δt = 120 s, 4 robots (κ = 4/3):
    # κ Δt λ_K = 0.512, so the poles stay within √0.5 up to s = 0.6 / 0.512
    top = stable_shares([-0.1, 0.6, 0.2], np.tile(0.0032 * np.eye(2), (3, 1, 1)), 120.0, 4)
    np.testing.assert_allclose(top, [0.6 / 0.512, 0.0, 0.3 / 0.512])
    # the poles of z² − (1 + a) z + a + s κ Δt λ at that share: modulus √0.5
    z = np.roots([1.0, -0.9, -0.1 + top[0] * 0.512])
    np.testing.assert_allclose(np.abs(z), np.sqrt(0.5))
    # no pull, no bound
    assert stable_shares([0.0], np.zeros((1, 2, 2)), 120.0, 4)[0] == np.inf
    # and the match keeps each share within its bound
    m = PlaceMatch(1, memory=1e9, min_samples=1, update_every=1)
    for k in range(50):
        m.observe(k, [[1.0, 0.0]], [[5.0, 0.0]], [[0.0, 0.0]], [np.eye(2)], top[:1])
    assert m.shares[0] == top[0]


def test_a_lower_bound_from_a_new_law_takes_effect_at_once():
    m = PlaceMatch(2, memory=1e9, min_samples=1, update_every=100)
    m.shares = np.array([2.0, 0.5])
    # between corrections: a share above a new law's bound comes down to it at once,
    # one below it stays
    assert m.observe(0.0, np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)),
                     np.tile(np.eye(2), (2, 1, 1)), np.array([1.0, 1.0]))
    np.testing.assert_allclose(m.shares, [1.0, 0.5])
