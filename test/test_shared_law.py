"""The shared interaction law: hand-computed features, neighbour search against brute force,
the model file round trip, and recovery of known parameters by the online estimator."""
import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.estimation.online_fit import OnlineHerdEstimator
from herd_ros.model.model_file import load_model_body
from herd_ros.model.rbf_field import FieldGrid, RbfBasis
from herd_ros.model.shared_law import (DistanceProfile, interaction_features,
                                       load_shared_model, make_shared_truth, save_shared_model,
                                       shared_model_from_dict, shared_rows)
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.synthesis.known_truth import circulating_field

PROFILE = DistanceProfile.even(60.0, 6)


def test_profile_by_hand():
    assert PROFILE.centers == pytest.approx((5, 15, 25, 35, 45, 55))
    assert PROFILE.width == pytest.approx(20 / 3)
    d = 20.0
    taper = 0.5 * (1 + np.cos(np.pi * d / 60))
    expected = np.exp(-(d - np.array([5, 15, 25, 35, 45, 55])) ** 2 / (2 * (20 / 3) ** 2)) * taper
    assert np.allclose(PROFILE.features(d), expected)
    assert np.all(PROFILE.features(60.0) == 0) and np.all(PROFILE.features(75.0) == 0)


def test_two_agents_feel_equal_and_opposite_features():
    p = np.array([[0.0, 0.0], [30.0, 40.0], [500.0, 0.0]])   # third agent out of range
    inter, valid = interaction_features(p, PROFILE)
    e = np.array([0.6, 0.8])
    assert np.allclose(inter[0], PROFILE.features(50.0)[:, None] * e)
    assert np.allclose(inter[1], -inter[0])
    assert np.all(inter[2] == 0) and valid.all()


def test_neighbours_match_brute_force():
    rng = np.random.default_rng(0)
    p = rng.uniform(0, 300, size=(400, 2))
    inter, _ = interaction_features(p, PROFILE)
    off = p[None, :, :] - p[:, None, :]
    d = np.sqrt((off ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    with np.errstate(invalid='ignore'):
        e = np.nan_to_num(off / d[..., None])
    brute = np.einsum('ijb,ijk->ibk', PROFILE.features(np.where(np.isinf(d), 1e9, d)), e)
    assert np.allclose(inter, brute)


def test_coincident_and_missing_agents_are_invalid():
    p = np.array([[0.0, 0.0], [0.0, 0.0], [10.0, 0.0], [np.nan, np.nan]])
    H, valid = shared_rows(p, p + 1.0, 1.0, PROFILE, RbfBasis(np.zeros((1, 2)), [10.0]))
    assert list(valid) == [False, False, True, False]
    assert H.shape == (4, 2, 1 + 6 + 2)


def _truth(n=40, seed=3):
    grid = FieldGrid(4, 4, (-100.0, 100.0, -100.0, 100.0))
    basis = RbfBasis.from_grid(grid)
    unity = grid.sigma * np.sqrt(2 * np.pi) / np.mean(grid.spacing) ** 2
    truth = make_shared_truth(
        n, seed=seed, profile=PROFILE, basis=basis, noise_std=0.05,
        field_fn=lambda c: circulating_field(c, (0, 0), 100.0) / unity)
    return truth, grid


def test_model_file_round_trip(tmp_path):
    truth, _ = _truth(5)
    truth.theta_se = [np.ones(1 + 6 + 32)] * 5
    path = save_shared_model(truth, tmp_path / 'shared.yaml')
    body = load_model_body(path)
    assert body['kind'] == 'schwager2007_shared' and body['interaction_radius'] == 60.0
    back = load_shared_model(path)
    p = np.random.default_rng(1).uniform(-50, 50, size=(5, 2))
    assert np.allclose(back.drift(p), truth.drift(p))
    body['agent_1']['profile'] = [1.0]
    with pytest.raises(HerdInputError, match='profile needs 6'):
        shared_model_from_dict(body, 'shared.yaml')


def test_online_estimator_recovers_a_shared_law_herd():
    truth, grid = _truth(40)
    rng = np.random.default_rng(4)
    run = simulate(truth, 1500, rng.uniform(-40, 40, size=(40, 2)), seed=5)
    est = OnlineHerdEstimator(run.agents, 1.0, 'shared', (4, 4), grid.bounds,
                              interaction_radius=60.0, profile_size=6)
    for t, p in zip(run.times, run.positions):
        est.add_snapshot(t, p)
    damping_err = np.abs(est.theta[:, 0] - truth.damping) / truth.damping
    assert np.median(damping_err) < 0.02 and damping_err.max() < 0.06, damping_err
    # the herd-wide force profile over the distances the data cover
    d = np.linspace(5, 50, 40)
    true_f = PROFILE.force(truth.profile_coef.mean(0), d)
    est_f = PROFILE.force(est.theta[:, 1:7].mean(0), d)
    assert np.sqrt(np.mean((est_f - true_f) ** 2)) < 0.2 * np.abs(true_f).max()
    model = est.model()
    assert model.n_agents == 40 and np.isfinite(model.damping).all()
    # one-step predictions of the learned law are as good as the truth's (within 5 %)
    w_fit = model.residuals(run.positions[-300:])
    w_true = truth.residuals(run.positions[-300:])
    assert np.sqrt(np.mean(w_fit ** 2)) <= 1.05 * np.sqrt(np.mean(w_true ** 2))


def test_missing_animal_drops_out_of_its_neighbours_sums():
    truth, grid = _truth(30, seed=7)
    run = simulate(truth, 30, np.random.default_rng(2).uniform(-90, 90, (30, 2)), seed=1)
    p = run.positions.copy()
    p[20:, 0] = np.nan                                    # agent 1 stops reporting
    est = OnlineHerdEstimator(run.agents, 1.0, 'shared', (4, 4), grid.bounds)
    for t, snap in zip(run.times, p):
        est.add_snapshot(t, snap)
    last = run.positions[19, 0]
    near = np.hypot(*(run.positions[:, :, :] - last).transpose(2, 0, 1)) < 60.0  # (T, N)
    assert est.samples[0] == 18                           # τ = 0..17 have its u^{τ+1}
    assert near[20:28, 1:].any()                           # it had neighbours ...
    assert (est.samples[1:] == 28).all()                   # ... who keep learning without it
    assert np.isfinite(est.theta).all()
