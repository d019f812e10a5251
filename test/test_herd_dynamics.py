"""HerdDynamics, the one model object (issue 26): each method against known truth or a
hand-computed case."""
import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.herd_dynamics import FitOptions, HerdDynamics
from herd_ros.model.herd_model import AgentLaw, HerdModel
from herd_ros.model.model_structure import ModelStructure
from herd_ros.model.rbf_field import RbfBasis
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model

BOUNDS = (-75.0, 75.0, -75.0, 75.0)


@pytest.fixture(scope='module')
def known():
    truth = make_truth_model(3, seed=4, grid=(4, 4), bounds=BOUNDS)
    run = HerdDynamics(model=truth).simulate(initial_positions(truth, seed=4, spread=25),
                                             6000, seed=99)
    return truth, run


def damping_only(dampings, dt=1.0):
    agents = [f'a{k}' for k in range(len(dampings))]
    basis = RbfBasis(np.zeros((0, 2)), [])
    laws = {a: AgentLaw(d, [b for b in agents if b != a], np.zeros(len(agents) - 1),
                        np.zeros(len(agents) - 1), basis, [], [], np.eye(2) * 0.01)
            for a, d in zip(agents, dampings)}
    return HerdModel(agents, dt, laws)


def test_simulate_without_noise_is_the_hand_computed_recursion():
    """Damping only: u^{τ+1} = a u^τ, p^{τ+1} = p^τ + Δt u^τ."""
    dyn = HerdDynamics(model=damping_only([0.5, 0.9], dt=2.0))
    traj = dyn.simulate([[0.0, 0.0], [10.0, 0.0]], 4, [[1.0, 0.0], [0.0, 1.0]], noise=False)
    # agent 0: u = 1, 0.5, 0.25 -> p = 0, 2, 3, 3.5 (× Δt = 2 on each velocity)
    np.testing.assert_allclose(traj.positions[:, 0, 0], [0.0, 2.0, 3.0, 3.5])
    np.testing.assert_allclose(traj.positions[:, 1, 1], [0.0, 2.0, 3.8, 5.42])
    np.testing.assert_allclose(traj.times, [0.0, 2.0, 4.0, 6.0])


def test_predict_reproduces_the_deterministic_law_and_its_covariance_grows(known):
    truth, _ = known
    dyn = HerdDynamics(model=truth)
    run = dyn.simulate(initial_positions(truth, seed=1, spread=25), 60, seed=1, noise=False)
    for k in (1, 5):
        pred, cov = dyn.predict(run.positions, steps=k, return_cov=True)
        assert np.isnan(pred[:k + 1]).all()
        np.testing.assert_allclose(pred[k + 1:], run.positions[k + 1:], atol=1e-9)
        assert cov.shape == pred.shape + (2,)
    _, c1 = dyn.predict(run.positions, 1, return_cov=True)
    _, c5 = dyn.predict(run.positions, 5, return_cov=True)
    t = 30
    assert (np.linalg.eigvalsh(c1[t]) >= 0).all()
    assert (np.trace(c5[t], axis1=-2, axis2=-1) > np.trace(c1[t], axis1=-2, axis2=-1)).all()


def test_fit_recovers_the_dampings_and_scores_against_the_baselines(known):
    truth, run = known
    dyn = HerdDynamics(options=FitOptions(grids=[(4, 4)], bounds=BOUNDS, field='fitted',
                                          noise='gaussian', memories=()))
    assert dyn.fit(run) is dyn
    got = np.array([dyn.coefficients[a][0] for a in truth.agents])
    np.testing.assert_allclose(got, truth.damping, rtol=0.02)
    assert dyn.parameter_names[truth.agents[0]][0] == 'damping'
    assert dyn.choices['terms'] == 'damping+interactions+field'
    score = dyn.score(run)
    one = score['one_step_rms']
    assert one['model']['herd'] < one['constant_velocity']['herd']
    assert one['model']['herd'] < one['stay_put']['herd']
    assert set(score['free_run']) >= {'herd', 'agents'}


def test_partial_fit_learns_the_same_dampings_online(known):
    truth, run = known
    dyn = HerdDynamics.online_learner(truth.agents, run.dt, field_grid=(4, 4),
                                      field_bounds=BOUNDS)
    for t, p in zip(run.times, run.positions):
        dyn.partial_fit(t, p)
    got = np.array([dyn.coefficients[a][0] for a in truth.agents])
    np.testing.assert_allclose(got, truth.damping, rtol=0.02)


def test_a_finer_herd_clock_is_skipped_between_model_steps(known):
    # the same run on a clock four times finer (gps_ingest at a fine step, the law at the
    # run's): the snapshots in between are skipped, and what is learned is exactly what the
    # model's own clock gives; a step longer than dt still breaks the chain
    truth, run = known
    steps = 400
    coarse = HerdDynamics.online_learner(truth.agents, run.dt, field_grid=(4, 4),
                                         field_bounds=BOUNDS)
    fine = HerdDynamics.online_learner(truth.agents, run.dt, field_grid=(4, 4),
                                       field_bounds=BOUNDS)
    statuses = []
    for k in range(steps):
        t, p = float(run.times[k]), run.positions[k]
        coarse.partial_fit(t, p)
        statuses.append(fine.partial_fit(t, p).status)
        if k + 1 < steps:
            for j in (1, 2, 3):       # whatever is between (a fresher pose, a stale one)
                q = p + j * 0.25 * (run.positions[k + 1] - p)
                statuses.append(fine.partial_fit(t + j * 0.25 * run.dt, q).status)
    assert statuses.count('between') == 3 * (steps - 1)
    assert 'gap' not in statuses and statuses.count('updated') == steps - 2
    np.testing.assert_array_equal(fine.online.theta, coarse.online.theta)
    assert fine.partial_fit(float(run.times[steps - 1]) + 1.5 * run.dt,
                            run.positions[steps]).status == 'gap'


def test_partial_fit_needs_an_online_learner():
    with pytest.raises(HerdInputError, match='online learner'):
        HerdDynamics(model=damping_only([0.9, 0.9])).partial_fit(0.0, np.zeros((2, 2)))
    with pytest.raises(HerdInputError, match='no model yet'):
        HerdDynamics().coefficients


def test_save_load_and_published_parameters_give_the_same_law(tmp_path, known):
    truth, run = known
    path = HerdDynamics(model=truth).save(tmp_path / 'm.yaml')
    back = HerdDynamics.load(path)
    for a in truth.agents:
        np.testing.assert_allclose(back.coefficients[a], truth.laws[a].theta, atol=1e-9)
    # the estimator's θ matrix and structure (every centre of the grid) give the same drift
    est = HerdDynamics.online_learner(truth.agents, 1.0, field_grid=(3, 3),
                                      field_bounds=BOUNDS)
    theta = np.random.default_rng(0).normal(0, 0.01, est.online.theta.shape)
    theta[:, 0] = 0.8
    structure = ModelStructure.from_json(est.online.structure().to_json())
    model = HerdDynamics.from_parameters(theta, structure).model
    for i, a in enumerate(truth.agents):
        np.testing.assert_allclose(model.laws[a].theta, theta[i])
    p = run.positions[100]
    u = np.ones_like(p)
    H, _ = est.online.regressor.rows(p - u, p, 1.0)      # rows from p^τ = p − u, p^{τ+1} = p
    np.testing.assert_allclose(model.next_velocity(u, p - u),
                               np.einsum('nkp,np->nk', H, theta), atol=1e-12)
