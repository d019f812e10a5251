"""Safety layer: speed limit, fence (convex and not), circular obstacles, stale data."""
import numpy as np
import pytest

from herd_ros.control.safety import (Fence, Obstacles, limit_speed, polygon_from_flat,
                                     safe_velocity, stale_mask)
from herd_ros.errors import HerdInputError

SQUARE = Fence(np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float))
# a non-convex "U" (clockwise, to exercise both orientations)
U_SHAPE = Fence(np.array([[0, 0], [0, 10], [3, 10], [3, 3], [7, 3], [7, 10], [10, 10],
                          [10, 0]], float))


def path_points(p, v, h, n=201):
    s = np.linspace(0, 1, n)[:, None, None]
    return p[None] + s * h * v[None]                       # (n, N, 2)


def test_speed_limit():
    out = limit_speed(np.array([[3.0, 4.0], [0.1, 0.0]]), 2.0)
    np.testing.assert_allclose(out, [[1.2, 1.6], [0.1, 0.0]])


def test_stale_mask():
    last = np.array([np.nan, 9.0, 9.6, 10.0])
    assert stale_mask(last, 10.0, 0.5).tolist() == [True, True, False, False]


def test_robot_heading_out_stops_margin_short_and_keeps_sliding():
    p = np.array([[9.0, 5.0]])
    v, _ = SQUARE.safe_velocity(p, np.array([[2.0, 1.0]]), horizon=1.0, margin=0.5)
    assert v[0, 0] == pytest.approx(0.5)                  # up to 0.5 m from the east edge
    assert v[0, 1] == pytest.approx(1.0)                  # along the fence: untouched
    v, _ = SQUARE.safe_velocity(np.array([[9.6, 5.0]]), np.array([[1.0, 0.0]]), 1.0, 0.5)
    np.testing.assert_allclose(v, [[0.0, 0.0]], atol=1e-12)


def test_inward_velocities_pass_unchanged():
    rng = np.random.default_rng(0)
    p = rng.uniform(3, 7, size=(100, 2))
    v = rng.normal(scale=0.5, size=(100, 2))
    out, changed = SQUARE.safe_velocity(p, v, horizon=1.0, margin=0.5)
    np.testing.assert_array_equal(out, v)
    assert not changed.any()


@pytest.mark.parametrize('fence', [SQUARE, U_SHAPE], ids=['square', 'u-shape'])
def test_commanded_paths_never_leave_the_fence(fence):
    rng = np.random.default_rng(3)
    p = rng.uniform(0, 10, size=(3000, 2))
    p = p[fence.contains(p)]
    v = rng.normal(scale=3.0, size=p.shape)
    h = rng.uniform(0.1, 2.0)
    out, _ = fence.safe_velocity(p, v, horizon=h, margin=0.2)
    pts = path_points(p, out, h).reshape(-1, 2)
    assert fence.contains(pts).all()                       # independent: matplotlib's Path
    assert (np.hypot(*out.T) <= np.hypot(*v.T) + 1e-9).all()
    moving = np.hypot(*out.T) > 1e-9
    assert moving.mean() > 0.5                             # safety does not just freeze robots


def test_robot_outside_may_only_return():
    p = np.array([[12.0, 5.0], [12.0, 5.0]])
    out, _ = SQUARE.safe_velocity(p, np.array([[1.0, 0.0], [-1.0, 1.0]]), 1.0, 0.0)
    np.testing.assert_allclose(out, [[0.0, 0.0], [-1.0, 0.0]], atol=1e-12)


def test_bad_fence_parameters():
    assert polygon_from_flat([]) is None
    with pytest.raises(HerdInputError, match='fence'):
        polygon_from_flat([0, 0, 1, 1, 2])
    with pytest.raises(HerdInputError, match='zero area'):
        Fence(np.array([[0, 0], [1, 1], [2, 2]], float))
    with pytest.raises(HerdInputError, match='radius'):
        Obstacles.from_flat([0, 0, -1])


def test_paths_never_enter_obstacles():
    obstacles = Obstacles.from_flat([5, 5, 1.5, 2, 8, 1.0])
    rng = np.random.default_rng(4)
    p = rng.uniform(0, 10, size=(3000, 2))
    p = p[obstacles.collisions(p, 0.3) == 0]
    v = rng.normal(scale=3.0, size=p.shape)
    out, _ = obstacles.safe_velocity(p, v, horizon=1.0, margin=0.3)
    pts = path_points(p, out, 1.0).reshape(-1, 2)
    d = np.hypot(*(pts[:, None, :] - obstacles.centers[None]).transpose(2, 0, 1))
    assert (d >= obstacles.radii + 0.3 - 1e-9).all()


def test_head_on_approach_stops_at_the_inflated_disc():
    obstacles = Obstacles.from_flat([5, 0, 2])
    out, _ = obstacles.safe_velocity(np.array([[0.0, 0.0]]), np.array([[1.0, 0.0]]), 10.0, 0.5)
    # the straight path meets the disc of radius 2.5 at x = 2.5: 2.5 m in 10 s
    np.testing.assert_allclose(out, [[0.25, 0.0]], atol=1e-12)
    # passing by at a tangent keeps the tangential part
    out, _ = obstacles.safe_velocity(np.array([[5.0, -2.5]]), np.array([[1.0, 1.0]]), 1.0, 0.5)
    np.testing.assert_allclose(out, [[1.0, 0.0]], atol=1e-12)
    out = obstacles.shorten(np.array([[0.0, 0.0]]), np.array([[1.0, 0.0]]), 10.0, 0.5)
    np.testing.assert_allclose(out, [[0.25, 0.0]])      # 2.5 m in 10 s


def test_collision_counts():
    obstacles = Obstacles.from_flat([0, 0, 1, 3, 0, 1])
    counts = obstacles.collisions(np.array([[0, 0], [1.5, 0], [10, 10]], float), 0.6)
    assert counts.tolist() == [1, 2, 0]


def test_whole_layer_respects_speed_fence_and_obstacles_together():
    obstacles = Obstacles.from_flat([5, 6, 1.0])
    rng = np.random.default_rng(5)
    p = rng.uniform(0, 10, size=(4000, 2))
    p = p[U_SHAPE.contains(p) & (obstacles.collisions(p, 0.2) == 0)]
    v = rng.normal(scale=4.0, size=p.shape)
    out, report = safe_velocity(p, v, horizon=0.5, max_speed=2.0, fence=U_SHAPE,
                                obstacles=obstacles, margin=0.2)
    assert (np.hypot(*out.T) <= 2.0 + 1e-9).all()
    pts = path_points(p, out, 0.5).reshape(-1, 2)
    assert U_SHAPE.contains(pts).all()
    assert (np.hypot(*(pts - [5, 6]).T) >= 1.2 - 1e-9).all()
    assert report['speed_limited'].any() and report['fence_limited'].any()
