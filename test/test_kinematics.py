"""Robot kinematics: frames (REP-103), limits, holonomic and unicycle motion, heading control."""
import numpy as np
import pytest

from herd_ros.control import kinematics as kin
from herd_ros.errors import HerdInputError


def test_body_frame_is_x_forward_y_left_yaw_ccw_from_east():
    yaw = np.array([0.0, np.pi / 2, np.pi, -np.pi / 2])
    forward = kin.body_to_world(np.tile([1.0, 0.0], (4, 1)), yaw)
    np.testing.assert_allclose(forward, [[1, 0], [0, 1], [-1, 0], [0, -1]], atol=1e-12)
    left = kin.body_to_world(np.tile([0.0, 1.0], (4, 1)), yaw)
    np.testing.assert_allclose(left, [[0, 1], [-1, 0], [0, -1], [1, 0]], atol=1e-12)


def test_world_to_body_inverts_body_to_world():
    rng = np.random.default_rng(0)
    body, yaw = rng.normal(size=(50, 2)), rng.uniform(-4, 4, 50)
    np.testing.assert_allclose(kin.world_to_body(kin.body_to_world(body, yaw), yaw), body,
                               atol=1e-12)


def test_limit_norm_keeps_direction_and_short_vectors():
    out = kin.limit_norm(np.array([[3.0, 4.0], [0.3, 0.4], [0.0, 0.0]]), 1.0)
    np.testing.assert_allclose(out, [[0.6, 0.8], [0.3, 0.4], [0, 0]])


def test_holonomic_respects_acceleration_and_speed_limits():
    state = kin.FleetState.at_rest([[0, 0, np.pi / 2]])
    # body forward at yaw 90° is north; commanded 5 m/s, limited to 2 m/s, 1 m/s² at h 0.1 s
    state = kin.step_holonomic(state, [[5.0, 0.0]], [0.0], 0.1, max_speed=2.0, max_accel=1.0)
    np.testing.assert_allclose(state.velocity, [[0.0, 0.1]], atol=1e-12)
    np.testing.assert_allclose(state.positions, [[0.0, 0.01]], atol=1e-12)
    for _ in range(100):
        state = kin.step_holonomic(state, [[5.0, 0.0]], [0.0], 0.1, 2.0, 1.0)
    np.testing.assert_allclose(state.velocity, [[0.0, 2.0]], atol=1e-12)


def test_holonomic_moves_sideways_without_turning():
    state = kin.FleetState.at_rest([[1.0, 2.0, 0.0]])
    state = kin.step_holonomic(state, [[0.0, 0.5]], [0.0], 2.0, max_speed=1.0)
    np.testing.assert_allclose(state.positions, [[1.0, 3.0]])
    assert state.yaw[0] == 0.0


def test_unicycle_drives_a_circle_of_radius_v_over_omega():
    h, steps = 0.01, 1000
    v, omega = 2 * np.pi * 2.0 / (steps * h), 2 * np.pi / (steps * h)   # R = v/ω = 2 m
    state = kin.FleetState.at_rest([[0.0, 0.0, 0.0]])
    path = []
    for _ in range(steps):
        state = kin.step_unicycle(state, [v], [omega], h, max_speed=5.0)
        path.append(state.positions[0].copy())
    path = np.array(path)
    # a left turn (ω > 0, CCW) about the centre (0, R), R = v/ω = 2
    np.testing.assert_allclose(np.hypot(path[:, 0], path[:, 1] - 2.0), 2.0, atol=1e-4)
    np.testing.assert_allclose(path[-1], [0, 0], atol=1e-3)


def test_unicycle_speed_ramps_with_max_accel():
    state = kin.FleetState.at_rest([[0, 0, 0], [0, 5, np.pi]])
    state = kin.step_unicycle(state, [1.0, 1.0], [0.0, 0.0], 0.1, max_speed=1.0, max_accel=0.5)
    np.testing.assert_allclose(state.velocity, [[0.05, 0], [-0.05, 0]], atol=1e-12)


def test_tracking_turns_toward_the_desired_course_and_never_reverses():
    desired = np.array([[0.0, 1.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 0.0]])
    forward, omega = kin.unicycle_tracking(desired, np.zeros(4), heading_gain=2.0,
                                           max_yaw_rate=1.0)
    np.testing.assert_allclose(forward, [0.0, 1.0, 0.0, 0.0], atol=1e-12)
    assert omega[0] == pytest.approx(1.0)          # left turn toward north, clipped at 1 rad/s
    assert omega[1] == 0.0 and omega[3] == 0.0
    rng = np.random.default_rng(1)
    w, yaw = rng.normal(size=(200, 2)), rng.uniform(-np.pi, np.pi, 200)
    fwd, _ = kin.unicycle_tracking(w, yaw)
    realised = kin.realised_world_velocity(fwd, np.zeros(200), yaw, 'unicycle')
    assert (np.hypot(*realised.T) <= np.hypot(*w.T) + 1e-12).all()
    assert ((realised * w).sum(-1) >= -1e-12).all()


def test_unicycle_closed_loop_converges_to_a_desired_world_velocity():
    target = np.array([[np.cos(2.0), np.sin(2.0)]]) * 0.8
    state = kin.FleetState.at_rest([[0, 0, -1.0]])
    for _ in range(400):
        fwd, _, omega = kin.twist_from_world_velocity(target, state.yaw, 'unicycle', 2.0, 1.5)
        state = kin.step_unicycle(state, fwd, omega, 0.05, max_speed=1.0, max_accel=2.0)
    np.testing.assert_allclose(state.velocity, target, atol=1e-3)
    assert state.yaw[0] == pytest.approx(2.0, abs=1e-3)


def test_holonomic_twist_realises_the_world_velocity():
    rng = np.random.default_rng(2)
    w, yaw = rng.normal(size=(20, 2)), rng.uniform(-3, 3, 20)
    vx, vy, omega = kin.twist_from_world_velocity(w, yaw, 'holonomic')
    np.testing.assert_allclose(kin.realised_world_velocity(vx, vy, yaw, 'holonomic'), w,
                               atol=1e-12)
    assert (omega == 0).all()


def test_unknown_kinematics_is_rejected():
    with pytest.raises(HerdInputError, match='kinematics'):
        kin.twist_from_world_velocity(np.zeros((1, 2)), np.zeros(1), 'tank')
