"""The structured QR solver against an independent dense least-squares solution."""
import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.estimation.batch_ls import fit_agent
from herd_ros.model.regressors import AgentRegression


def random_regression(m=400, pa=5, K=7, seed=0, noise=0.1):
    rng = np.random.default_rng(seed)
    A_x, A_y = rng.normal(size=(m, pa)), rng.normal(size=(m, pa))
    F = np.abs(rng.normal(size=(m, K)))
    theta = rng.normal(size=pa + 2 * K)
    reg = AgentRegression('a', ['b'], A_x, A_y, F, np.zeros(m), np.zeros(m))
    phi, _ = reg.design()
    y = phi @ theta + noise * rng.normal(size=2 * m)
    reg.y_x, reg.y_y = y[:m], y[m:]
    return reg, theta


def test_structured_qr_equals_dense_lstsq():
    reg, _ = random_regression()
    phi, y = reg.design()
    expected = np.linalg.lstsq(phi, y, rcond=None)[0]
    fit = fit_agent(reg, stable=False)     # the solver itself (random θ: a damping of 3)
    np.testing.assert_allclose(fit.theta, expected, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fit.residuals.T.ravel(), y - phi @ expected, atol=1e-10)


def test_ols_standard_errors_match_textbook_formula():
    reg, _ = random_regression(seed=3)
    phi, y = reg.design()
    theta = np.linalg.lstsq(phi, y, rcond=None)[0]
    r = y - phi @ theta
    s2 = r @ r / (len(y) - len(theta))
    # independent: textbook sigma^2 (Phi^T Phi)^-1 via a solve on the Gram matrix
    expected = np.sqrt(s2 * np.diag(np.linalg.solve(phi.T @ phi, np.eye(len(theta)))))
    np.testing.assert_allclose(fit_agent(reg, se='ols').theta_se, expected, rtol=1e-8)


def test_ridge_equals_augmented_dense_problem():
    reg, _ = random_regression(seed=1)
    phi, y = reg.design()
    lam = 0.3
    D = np.sqrt(lam) * np.linalg.norm(phi, axis=0)
    D[0] = 0.0                  # the damping (θ's first entry) is not penalised
    expected = np.linalg.lstsq(np.vstack([phi, np.diag(D)]),
                               np.concatenate([y, np.zeros(len(D))]), rcond=None)[0]
    np.testing.assert_allclose(fit_agent(reg, ridge=lam).theta, expected, rtol=1e-9)


def test_a_strong_ridge_leaves_the_damping_where_the_data_put_it():
    """Issue 26: the ridge must not pull the damping towards stay-put. With a huge λ every
    other coefficient goes to 0, and the damping becomes the least-squares damping of the
    damping column alone (hand-computed here from the design)."""
    reg, _ = random_regression(seed=1)
    phi, y = reg.design()
    theta = fit_agent(reg, ridge=1e9).theta
    a_alone = float(phi[:, 0] @ y / (phi[:, 0] @ phi[:, 0]))
    assert abs(theta[0] - a_alone) < 1e-4 * abs(a_alone)
    assert np.abs(theta[1:]).max() < 1e-4


def test_recovers_parameters_without_noise():
    reg, theta = random_regression(noise=0.0, seed=2)
    np.testing.assert_allclose(fit_agent(reg).theta, theta, rtol=1e-9, atol=1e-10)


def test_singular_design_is_one_clear_error():
    reg, _ = random_regression(seed=4)
    reg.A_x[:, 1] = reg.A_x[:, 0]
    reg.A_y[:, 1] = reg.A_y[:, 0]
    with pytest.raises(HerdInputError, match='singular data'):
        fit_agent(reg)
    assert np.isfinite(fit_agent(reg, ridge=1e-3).theta).all()


def test_fewer_samples_than_parameters():
    reg, _ = random_regression(m=5, pa=5, K=7)
    with pytest.raises(HerdInputError, match='fewer samples than parameters'):
        fit_agent(reg)


def test_a_ridge_does_not_shrink_the_known_dampings():
    """Issue 26: on a known-truth herd (3 animals, field and interactions on), the full
    model with λ = 0.1 kept every damping ~12 % low when the damping was penalised; now
    within 2 % (as with λ = 0)."""
    from herd_ros.estimation.herd_fit import fit_herd
    from herd_ros.simulation.herd_simulator import simulate
    from herd_ros.synthesis.known_truth import initial_positions, make_truth_model
    bounds = (-75.0, 75.0, -75.0, 75.0)
    truth = make_truth_model(3, seed=1, grid=(6, 6), bounds=bounds)
    run = simulate(truth, 6000, initial_positions(truth, seed=1, spread=25), seed=5)
    fit = fit_herd([run], grid=(6, 6), bounds=bounds, min_visits=1, ridge=0.1)
    for i, a in enumerate(truth.agents):
        true = truth.laws[a].damping
        got = fit.model.damping[fit.model.agents.index(a)]
        assert abs(got / true - 1) < 0.02, (a, got, true)


def test_an_unstable_damping_is_held_and_the_rest_refitted():
    """Issue 30: data whose unconstrained least squares give |a| ≥ 1 (an accelerating
    stretch) must not make an unstable law: the damping is held at DAMPING_MAX, the other
    terms are the least squares with it held (computed here with numpy's lstsq)."""
    from herd_ros.estimation.batch_ls import DAMPING_MAX, fit_agent
    from herd_ros.model.regressors import AgentRegression
    rng = np.random.default_rng(4)
    m = 400
    u = np.zeros((m + 1, 2))
    u[0] = (0.3, -0.2)
    for t in range(m):
        u[t + 1] = 1.01 * u[t] + rng.normal(0, 0.01, 2)          # a = 1.01: unstable
    ux, uy = u[:-1, 0], u[:-1, 1]
    e = rng.normal(0, 1, (m, 1))                                   # one interaction column
    A_x, A_y = np.column_stack([ux, e[:, 0]]), np.column_stack([uy, -e[:, 0]])
    F = np.exp(-rng.random((m, 2)))                                # two field features
    reg = AgentRegression('a', ['b'], A_x, A_y, F, u[1:, 0], u[1:, 1])
    # the stacked design [[A_x, F, 0], [A_y, 0, F]] in θ order [a, θ, fu.., fv..]
    Phi = np.block([[A_x, F, np.zeros_like(F)], [A_y, np.zeros_like(F), F]])
    Y = np.concatenate([reg.y_x, reg.y_y])
    free_ls = np.linalg.lstsq(Phi, Y, rcond=None)[0]
    assert free_ls[0] > 1.0                                        # unconstrained: unstable
    fit = fit_agent(reg)
    assert fit.theta[0] == DAMPING_MAX and 'held at' in fit.constrained
    held = np.linalg.lstsq(Phi[:, 1:], Y - DAMPING_MAX * Phi[:, 0], rcond=None)[0]
    assert np.allclose(fit.theta[1:], held, atol=1e-10)
    assert fit.theta_se[0] == 0.0 and (fit.theta_se[1:] > 0).all()
    # a stable fit is left alone
    u2 = u.copy()
    for t in range(m):
        u2[t + 1] = 0.9 * u2[t] + rng.normal(0, 0.01, 2)
    reg2 = AgentRegression('a', ['b'], np.column_stack([u2[:-1, 0], e[:, 0]]),
                           np.column_stack([u2[:-1, 1], -e[:, 0]]), F, u2[1:, 0], u2[1:, 1])
    assert fit_agent(reg2).constrained == '' and abs(fit_agent(reg2).theta[0] - 0.9) < 0.05
