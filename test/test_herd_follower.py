"""Robots following the herd law: hand-computed steps, assignment, rate handling, noise, topic."""
import numpy as np
import pytest

from herd_ros.control.herd_follower import (HerdFollower, model_from_parameter_matrix,
                                            robot_herd_model)
from herd_ros.errors import HerdInputError
from herd_ros.model.herd_model import AgentLaw, HerdModel
from herd_ros.model.rbf_field import FieldGrid, RbfBasis
from herd_ros.synthesis.known_truth import make_truth_model

FAR = RbfBasis(np.array([[1e6, 1e6]]), np.array([1.0]))   # one centre far away: g = 0 here


def two_animals(damping=(0.5, 0.8), theta1=(0.1, 0.2), theta2=(1.0, 3.0), noise=(0.0, 0.0)):
    laws = {
        'cow_a': AgentLaw(damping[0], ['cow_b'], [theta1[0]], [theta2[0]], FAR, [0.0], [0.0],
                          noise_cov=np.eye(2) * noise[0]),
        'cow_b': AgentLaw(damping[1], ['cow_a'], [theta1[1]], [theta2[1]], FAR, [0.0], [0.0],
                          noise_cov=np.eye(2) * noise[1]),
    }
    return HerdModel(['cow_a', 'cow_b'], 1.0, laws)


def test_one_model_step_by_hand():
    follower = HerdFollower(two_animals(), ['cow_a', 'cow_b'])
    p = np.array([[0.0, 0.0], [5.0, 0.0]])
    u = np.array([[0.2, 0.0], [0.0, 0.4]])
    out = follower.advance(u, p, elapsed=1.0)
    # robot 1: 0.5·u + (0.1 − 1/5)·(+x) ; robot 2: 0.8·u + (0.2 − 3/5)·(−x)
    np.testing.assert_allclose(out, [[0.1 - 0.1, 0.0], [0.4, 0.32]], atol=1e-12)


def test_assignment_swaps_laws():
    follower = HerdFollower(two_animals(), ['cow_b', 'cow_a'])
    p = np.array([[0.0, 0.0], [5.0, 0.0]])
    out = follower.advance(np.zeros((2, 2)), p, 1.0)
    # robot 1 now carries cow_b's law toward cow_a: (0.2 − 3/5) along +x
    np.testing.assert_allclose(out, [[-0.4, 0.0], [0.1, 0.0]], atol=1e-12)


def test_robots_on_the_same_animal_use_its_mean_pair_law():
    model = make_truth_model(3, seed=2)
    robots = robot_herd_model(model, ['agent_1', 'agent_1'], ['r1', 'r2'])
    i = 0
    assert robots.theta1[0, 1] == pytest.approx(model.theta1[i, [1, 2]].mean())
    assert robots.theta2[0, 1] == pytest.approx(model.theta2[i, [1, 2]].mean())


def test_identity_assignment_reproduces_the_animals_law():
    model = make_truth_model(3, seed=3)
    follower = HerdFollower(model, model.agents)
    rng = np.random.default_rng(0)
    p = rng.uniform(-60, 60, size=(3, 2))
    u = rng.normal(scale=0.3, size=(3, 2))
    np.testing.assert_allclose(follower.advance(u, p, model.dt), model.next_velocity(u, p),
                               rtol=1e-12, atol=1e-15)


def test_fractional_steps_relax_to_the_same_fixed_point():
    # constant drift F (robots far apart: pair forces θ1 − θ2/d with θ = 0 vanish)
    model = two_animals(theta1=(0.0, 0.0), theta2=(0.0, 0.0))
    model.laws['cow_a'].field_u[:] = 0.0
    follower = HerdFollower(model, ['cow_a', 'cow_b'])
    follower.environment = lambda p, active: np.array([[0.3, 0.0], [0.0, -0.2]])
    p = np.zeros((2, 2))
    u0 = np.zeros((2, 2))
    alpha, ticks = 0.1, 50
    u = u0
    for _ in range(ticks):
        u = follower.advance(u, p, elapsed=alpha * model.dt)
    a = np.array([0.5, 0.8])[:, None]
    fixed = np.array([[0.3, 0.0], [0.0, -0.2]]) / (1 - a)
    expected = fixed + (1 - alpha * (1 - a)) ** ticks * (u0 - fixed)     # closed form
    np.testing.assert_allclose(u, expected, rtol=1e-12)


def test_a_slow_controller_takes_whole_model_steps_with_positions_propagated():
    model = make_truth_model(3, seed=4)
    follower = HerdFollower(model, model.agents)
    rng = np.random.default_rng(1)
    p = rng.uniform(-40, 40, size=(3, 2))
    u = rng.normal(scale=0.3, size=(3, 2))
    out = follower.advance(u, p, elapsed=3 * model.dt)
    for _ in range(3):                          # the law itself, three times (eq. 2)
        u, p = model.next_velocity(u, p), p + model.dt * u
    np.testing.assert_allclose(out, u, rtol=1e-10)


def test_stale_robots_exert_nothing():
    follower = HerdFollower(two_animals(), ['cow_a', 'cow_b'])
    p = np.array([[0.0, 0.0], [5.0, 0.0]])
    out = follower.advance(np.zeros((2, 2)), p, 1.0, active=np.array([True, False]))
    np.testing.assert_allclose(out[0], [0.0, 0.0], atol=1e-12)
    p[1] = np.nan                                # never seen: no NaN leaks into the others
    out = follower.advance(np.zeros((2, 2)), p, 1.0)
    assert np.isfinite(out).all()


@pytest.mark.parametrize('alpha', [1.0, 0.25])
def test_noise_accumulates_q_per_model_step(alpha):
    q = (0.04, 0.01)
    model = two_animals(damping=(1.0, 1.0), theta1=(0, 0), theta2=(0, 0), noise=q)
    follower = HerdFollower(model, ['cow_a', 'cow_b'], noise=True, seed=7)
    samples = []
    for _ in range(4000):
        u = np.zeros((2, 2))
        for _ in range(int(round(1 / alpha))):   # one model step in 1/α ticks
            u = follower.advance(u, np.array([[0.0, 0.0], [50.0, 0.0]]), alpha)
        samples.append(u)
    samples = np.array(samples)
    for k in range(2):
        cov = np.cov(samples[:, k].T)
        np.testing.assert_allclose(np.diag(cov), [q[k], q[k]], rtol=0.1)
        assert abs(cov[0, 1]) < 0.1 * q[k]


def test_parameter_matrix_of_the_topic_rebuilds_the_model():
    model = make_truth_model(3, seed=5, grid=(4, 5), bounds=(-100, 100, -50, 50))
    theta = np.stack([model.laws[a].theta for a in model.agents])
    rebuilt = model_from_parameter_matrix(theta, model.agents, model.dt,
                                          FieldGrid(4, 5, (-100, 100, -50, 50)))
    p = np.random.default_rng(2).uniform(-50, 50, size=(3, 2))
    np.testing.assert_allclose(rebuilt.drift(p), model.drift(p), rtol=1e-12)
    with pytest.raises(HerdInputError, match='expected 3 agents'):
        model_from_parameter_matrix(theta[:, :-1], model.agents, 1.0,
                                    FieldGrid(4, 5, (-100, 100, -50, 50)))


def test_unknown_animal_in_assignment():
    with pytest.raises(HerdInputError, match='cow_z'):
        HerdFollower(two_animals(), ['cow_a', 'cow_z'])


@pytest.mark.parametrize('phase', [0.0, 0.13, 0.31])
def test_clock_hold_moves_the_discrete_law_on_the_herd_clock(phase):
    """A controller ticking 3.3 × per model step at an arbitrary phase: the robot's
    displacement over every herd-clock interval [kΔt, (k+1)Δt] is Δt·u^k of the discrete
    law, so the velocities measured on that clock obey u^{k+1} = a u^k (robot integrated
    here exactly: piecewise-constant commands)."""
    from herd_ros.control.herd_follower import HerdClockHold
    a, dt = 0.5, 2.0
    model = HerdModel(['cow'], dt, {'cow': AgentLaw(a, [], [], [], FAR, [0.0], [0.0])})
    follower = HerdFollower(model, ['cow'])
    hold = HerdClockHold(dt)
    h = dt / 3.3
    t, p, issued = phase * dt, np.zeros((1, 2)), np.array([[1.0, 0.0]])
    times, path = [t], [p.copy()]
    while t < 12 * dt:
        issued = hold.command(follower, issued, p, t)
        t_next = t + h
        p = p + h * issued
        t = t_next
        times.append(t)
        path.append(p.copy())
    times, path = np.array(times), np.array(path)[:, 0, 0]
    ticks = np.arange(2, 11) * dt
    at_ticks = np.interp(ticks, times, path)         # exact: the path is piecewise linear
    v = np.diff(at_ticks) / dt
    np.testing.assert_allclose(v[1:], a * v[:-1], rtol=1e-9)
    assert v[0] > 0


def test_the_clock_hold_restarts_after_a_jump_of_the_clock_instead_of_stepping_through_it():
    """A controller on sim time may see the clock jump by days (a replay started late or
    resumed): the hold steps the law once from what the robots did (as on its first tick),
    not 10⁸ times."""
    import time
    from herd_ros.control.herd_follower import HerdClockHold
    model = make_truth_model(3, seed=1)
    follower = HerdFollower(model, list(model.agents))
    hold = HerdClockHold(model.dt)
    p = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0]])
    issued = np.full((3, 2), 0.1)
    hold.command(follower, issued, p, 10.0)
    began = time.perf_counter()
    got = hold.command(follower, issued, p, 10.0 + 1e8 * model.dt)
    assert time.perf_counter() - began < 1.0
    np.testing.assert_allclose(got, follower.advance(issued, p, model.dt), rtol=1e-12)
