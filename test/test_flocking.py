"""Olfati-Saber / La & Sheng flocking: hand-computed functions, invariants of the law, and
the report's Table 1 made quantitative (issue 6, acceptance 1-4).

Expectations are independent of the code under test: values computed by hand from the
paper's formulas, conservation of momentum of the pairwise terms, and connectivity /
collisions recomputed here from the recorded positions with a brute-force distance matrix.
"""
import math

import numpy as np
import pandas as pd
import pytest
from scipy.sparse.csgraph import connected_components

from herd_ros.errors import HerdInputError
from herd_ros.flocking import metrics as fm
from herd_ros.flocking.olfati_saber import (CircularObstacles, FlockingParams, alpha_term,
                                            beta_agents, bump, flocking_acceleration,
                                            neighbour_pairs, phi, sigma_gradient, sigma_norm)
from herd_ros.flocking.scenarios import make_scenario, simulate

REPORT = FlockingParams()


def brute_connectivity(q, r):
    """rank(L)/(n−1) of the r-disc graph, from a dense distance matrix."""
    d = np.linalg.norm(q[:, None] - q[None], axis=2)
    adjacency = (d < r) & ~np.eye(len(q), dtype=bool)
    n_comp = connected_components(adjacency.astype(int), directed=False, return_labels=False)
    return (len(q) - n_comp) / (len(q) - 1)


def inside_any(q, obstacles):
    d = np.linalg.norm(q[:, None] - obstacles.centres[None], axis=2)
    return np.any(d < obstacles.radii[None], axis=1)


# --- the functions of Olfati-Saber 2006, by hand -------------------------------------------

def test_sigma_norm_and_gradient_hand_values():
    # ‖(3, 4)‖_σ = (√(1 + 0.1·25) − 1)/0.1 = (√3.5 − 1)·10
    assert sigma_norm([3.0, 4.0], 0.1) == pytest.approx((math.sqrt(3.5) - 1) * 10, rel=1e-12)
    assert sigma_norm([0.0, 0.0], 0.1) == 0.0
    np.testing.assert_allclose(sigma_gradient([3.0, 4.0], 0.1),
                               np.array([3.0, 4.0]) / math.sqrt(3.5), rtol=1e-12)
    # r_α for r = 9: (√(1 + 8.1) − 1)/0.1; d_α for d = 7.5: (√(1 + 5.625) − 1)/0.1
    assert REPORT.r_alpha == pytest.approx((math.sqrt(9.1) - 1) * 10)
    assert REPORT.d_alpha == pytest.approx((math.sqrt(6.625) - 1) * 10)


def test_bump_hand_values():
    z = np.array([-0.1, 0.0, 0.19, 0.2, 0.4, 0.6, 1.0, 1.5])
    expected = [0.0, 1.0, 1.0, 1.0, 0.5 * (1 + math.cos(math.pi / 4)), 0.5, 0.0, 0.0]
    np.testing.assert_allclose(bump(z, 0.2), expected, atol=1e-12)


def test_phi_hand_values():
    # a = b = 5: c = 0 and φ(z) = 5 z/√(1 + z²)
    assert phi(1.0, 5, 5) == pytest.approx(5 / math.sqrt(2))
    assert phi(-2.0, 5, 5) == pytest.approx(-10 / math.sqrt(5))
    assert phi(0.0, 5, 5) == pytest.approx(0.0)
    # a = 5, b = 15: c = 10/√300, φ(0) = ½[20·σ1(c) − 10] = 0, limits a and −b
    assert phi(0.0, 5, 15) == pytest.approx(0.0, abs=1e-12)
    assert phi(1e6, 5, 15) == pytest.approx(5, rel=1e-6)
    assert phi(-1e6, 5, 15) == pytest.approx(-15, rel=1e-6)


def test_pair_force_vanishes_at_spacing_repels_inside_attracts_outside():
    p = np.zeros((2, 2))

    def force_on_first(gap):
        q = np.array([[0.0, 0.0], [gap, 0.0]])
        u = alpha_term(q, p, neighbour_pairs(q, REPORT.range), REPORT)
        np.testing.assert_allclose(u[0], -u[1], atol=1e-12)  # action = reaction
        assert u[0, 1] == pytest.approx(0.0, abs=1e-12)
        return u[0, 0]

    assert force_on_first(REPORT.distance) == pytest.approx(0.0, abs=1e-9)
    assert force_on_first(5.0) < 0       # pushed away from the neighbour on its right
    assert force_on_first(8.5) > 0       # pulled towards it
    assert force_on_first(9.5) == 0.0    # out of range


def test_beta_agent_is_the_projection_on_the_circle():
    obstacles = CircularObstacles([[0.0, 0.0]], [10.0])
    q_hat, p_hat = beta_agents(np.array([[0.0, 20.0]]), np.array([[3.0, 4.0]]), obstacles)
    # μ = 10/20, q̂ = (0, 10), p̂ = μ P p = ½ (3, 0)
    np.testing.assert_allclose(q_hat[0, 0], [0.0, 10.0])
    np.testing.assert_allclose(p_hat[0, 0], [1.5, 0.0])
    moving = CircularObstacles([[0.0, 0.0]], [10.0], [[0.0, 1.0]])
    _, p_hat = beta_agents(np.array([[0.0, 20.0]]), np.array([[3.0, 4.0]]), moving)
    np.testing.assert_allclose(p_hat[0, 0], [1.5, 1.0])  # ½ P (p − v) + v
    np.testing.assert_allclose(moving.at_time(2.0).centres, [[0.0, 2.0]])


def test_beta_term_pushes_away_from_a_near_obstacle_only():
    obstacles = CircularObstacles([[0.0, 0.0]], [10.0])
    q = np.array([[12.0, 0.0], [30.0, 0.0]])
    params = REPORT.with_(c1_gamma=0.0, c2_gamma=0.0, c1_com=0.0, c2_com=0.0)
    u = flocking_acceleration(q, np.zeros((2, 2)), [0, 0], [0, 0], params, obstacles)
    assert u[0, 0] > 0 and u[0, 1] == pytest.approx(0.0)
    np.testing.assert_allclose(u[1], 0.0)


@pytest.mark.parametrize('mode,c1,c2', [
    ('plain', 15.0, 2 * math.sqrt(15)),
    ('global-com', 25.0, 2 * math.sqrt(15) + 2 * math.sqrt(10)),
])
def test_pair_terms_cancel_so_the_centre_of_mass_obeys_the_gamma_feedback(mode, c1, c2):
    # Σ_i u_i^α = 0 (antisymmetric pair terms), so the mean acceleration is the γ feedback
    # on the centre of mass alone.
    rng = np.random.default_rng(3)
    q, p = rng.uniform(0, 30, (40, 2)), rng.normal(0, 2, (40, 2))
    q_r, p_r = np.array([50.0, 10.0]), np.array([10.0, 0.0])
    u = flocking_acceleration(q, p, q_r, p_r, REPORT.with_(gamma_mode=mode))
    expected = -c1 * (q.mean(0) - q_r) - c2 * (p.mean(0) - p_r)
    np.testing.assert_allclose(u.mean(axis=0), expected, rtol=1e-9, atol=1e-9)


def test_local_com_of_an_isolated_agent_is_itself():
    q = np.array([[0.0, 0.0], [100.0, 0.0], [104.0, 0.0]])
    p = np.array([[1.0, 2.0], [0.0, 0.0], [0.0, 0.0]])
    q_r, p_r = np.array([10.0, -5.0]), np.array([3.0, 0.0])
    u = flocking_acceleration(q, p, q_r, p_r, REPORT.with_(gamma_mode='local-com'))
    expected = -25.0 * (q[0] - q_r) - (2 * math.sqrt(15) + 2 * math.sqrt(10)) * (p[0] - p_r)
    np.testing.assert_allclose(u[0], expected)


def test_neighbour_pairs_match_brute_force():
    q = np.random.default_rng(0).uniform(0, 60, (300, 2))
    d = np.linalg.norm(q[:, None] - q[None], axis=2)
    i, j = np.nonzero(np.triu(d < 9.0, k=1))
    assert set(map(tuple, neighbour_pairs(q, 9.0))) == set(zip(i, j))


def test_metrics_hand_values():
    q = np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0], [100.0, 0.0]])
    p = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [5.0, 0.0]])
    obstacles = CircularObstacles([[100.0, 1.0]], [2.0])
    m = fm.step_metrics(q, p, [28.75, 0.0], distance=7.5, radius=9.0, obstacles=obstacles)
    assert m['connectivity'] == pytest.approx(2 / 3)          # 4 agents, 2 components
    assert m['deviation_energy'] == pytest.approx(2 * 2 * 2.5 ** 2 / (4 + 1))
    assert m['velocity_mismatch'] == pytest.approx((3 * 1.0 + 9.0) / 4)  # p̄ = 2
    assert m['cohesion_radius'] == pytest.approx(100 - 28.75)
    assert m['tracking_mse'] == pytest.approx(0.0)
    assert m['collisions'] == 1
    honest = np.array([True, True, True, False])
    m = fm.step_metrics(q, p, [5.0, 0.0], 7.5, 9.0, obstacles, members=honest)
    assert m['connectivity'] == 1.0 and m['collisions'] == 0 and m['velocity_mismatch'] == 0.0


def test_bad_parameters_raise_one_clear_error():
    with pytest.raises(HerdInputError, match='gamma_mode'):
        FlockingParams(gamma_mode='nearest')
    with pytest.raises(HerdInputError, match='distance'):
        FlockingParams(distance=10.0)
    with pytest.raises(HerdInputError, match='triples'):
        CircularObstacles.from_flat([1.0, 2.0])
    with pytest.raises(HerdInputError, match='unknown'):
        FlockingParams.from_mapping({'c1_alfa': 3.0})
    assert len(CircularObstacles.from_flat([100.0, 50.0, 10.0, 0.0, 0.0, 1.0])) == 2


# --- acceptance: the report's experiments ---------------------------------------------------

@pytest.mark.parametrize('mode', ['plain', 'global-com', 'local-com'])
def test_free_space_connects_and_tracks(mode):
    """Acceptance 1: 50 agents, report gains, target at 10 m/s: connectivity reaches 1 and
    stays; the CoM-to-target error settles below 1 m."""
    run = simulate(make_scenario('free'), REPORT.with_(gamma_mode=mode), seed=0, duration=15.0,
                   record_every=5, with_metrics=False)
    conn = np.array([brute_connectivity(q, 9.0) for q in run.positions])
    first = int(np.argmax(conn == 1.0))
    assert conn[first] == 1.0 and run.times[first] < 5.0
    assert np.all(conn[first:] == 1.0)
    err = np.linalg.norm(run.positions.mean(axis=1) - run.target_positions, axis=1)
    assert np.all(err[run.times >= 5.0] < 1.0)
    np.testing.assert_allclose(run.velocities[-1].mean(axis=0), [10.0, 0.0], atol=0.05)


def _ten_seeds(name, duration):
    scenario = make_scenario(name)
    for seed in range(10):
        yield scenario, simulate(scenario, REPORT, seed=seed, duration=duration,
                                 record_every=1, with_metrics=False)


def test_obstacle_no_collision_and_flock_rejoins():
    """Acceptance 2: circle (100, 50) r 10, 10 placements: nobody enters it; the flock is
    connected again once past it."""
    for scenario, run in _ten_seeds('obstacle', 16.0):
        assert not any(inside_any(q, scenario.obstacles).any() for q in run.positions), run.seed
        split = [brute_connectivity(q, 9.0) for q in run.positions[::10]]
        assert min(split) < 1.0  # the obstacle does split the flock (the test bites)
        late = run.times >= 14.0
        assert all(brute_connectivity(q, 9.0) == 1.0 for q in run.positions[late][::5]), run.seed


@pytest.mark.parametrize('name,duration', [('obstacles', 18.0), ('moving-obstacle', 14.0)])
def test_three_and_moving_obstacles_no_collision(name, duration):
    """Acceptance 3: three obstacles, and one moving at 5 m/s: zero collisions, 10 seeds."""
    for scenario, run in _ten_seeds(name, duration):
        for t, q in zip(run.times, run.positions):
            assert not inside_any(q, scenario.obstacles.at_time(t)).any(), (run.seed, t)


@pytest.mark.parametrize('mode', ['plain', 'global-com', 'local-com'])
@pytest.mark.parametrize('name', ['adversarial-static', 'adversarial-random'])
def test_adversaries_do_not_break_the_honest_flock(name, mode):
    """Acceptance 4: 5 of 50 adversaries: the others' velocity mismatch returns near zero and
    their connectivity stays >= 0.9 once they have gathered."""
    run = simulate(make_scenario(name, n_adversaries=5), REPORT.with_(gamma_mode=mode), seed=4,
                   duration=12.0, record_every=5, with_metrics=False)
    honest = ~run.adversaries
    assert honest.sum() == 45
    if name == 'adversarial-static':
        np.testing.assert_allclose(run.positions[-1, ~honest], run.positions[0, ~honest])
    conn = np.array([brute_connectivity(q[honest], 9.0) for q in run.positions])
    first = int(np.argmax(conn == 1.0))
    assert conn[first] == 1.0
    assert conn[first:].min() >= 0.9
    v = run.velocities[-1, honest]
    mismatch = np.mean(np.sum((v - v.mean(axis=0)) ** 2, axis=1))
    v0 = run.velocities[1, honest]
    assert mismatch < 0.1 < np.mean(np.sum((v0 - v0.mean(axis=0)) ** 2, axis=1))


# --- the command line ------------------------------------------------------------------------

def test_flock_cli_writes_files(tmp_path, capsys):
    from herd_ros.cli.main import main

    out = tmp_path / 'out'
    status = main(['flock', '--scenario', 'moving-obstacle', '--agents', '12', '--seeds', '2',
                   '--duration', '1.0', '--gif', '--params', 'config/flocking.yaml',
                   '--out', str(out)])
    assert status == 0
    metrics = pd.read_csv(out / 'metrics.csv')
    assert list(metrics.columns[:8]) == ['seed', 't', 'deviation_energy', 'velocity_mismatch',
                                         'cohesion_radius', 'connectivity', 'tracking_mse',
                                         'collisions']
    assert len(metrics) == 2 * 51
    traj = pd.read_csv(out / 'trajectories.csv')
    assert list(traj.columns) == ['seed', 'time', 'agent', 'x', 'y']
    assert len(traj) == 2 * 11 * 12
    assert list(pd.read_csv(out / 'target.csv').columns) == ['seed', 'time', 'x', 'y']
    for name in ('snapshots.png', 'metrics.png', 'tracking_error.png', 'animation.gif'):
        assert (out / name).stat().st_size > 1000
    assert 'moving-obstacle' in capsys.readouterr().out
    assert main(['flock', '--scenario', 'free', '--seeds', '0', '--out', str(out)]) == 2
