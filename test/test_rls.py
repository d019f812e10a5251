"""Batched recursive least squares (issue 4, acceptance 1 and 2).

Expectations are independent of the RLS code: the batch least-squares solution by QR
(batch_ls), known simulated parameters, and invariants of a covariance matrix.
"""
import numpy as np
import pytest

from herd_ros.estimation.batch_ls import fit_agent
from herd_ros.estimation.online_fit import OnlineHerdEstimator, online_fit
from herd_ros.estimation.rls import HerdRLS
from herd_ros.model.rbf_field import FieldGrid, RbfBasis
from herd_ros.model.regressors import agent_regression
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model

BOUNDS = (-75.0, 75.0, -75.0, 75.0)
GRID = (6, 6)


def recovery_run(n, seed, steps):
    """The recovery data of test_recovery.py."""
    truth = make_truth_model(n, seed=seed, grid=GRID, bounds=BOUNDS)
    return truth, simulate(truth, steps, initial_positions(truth, seed=seed, spread=25),
                           seed=seed + 1000)


def test_lambda_one_equals_batch_least_squares():
    truth, run = recovery_run(3, 3, 4000)
    p = run.positions
    grid = FieldGrid(*GRID, BOUNDS)
    # one basis for both: the cells every agent visited often (so the batch problem is regular)
    visits = np.min([grid.cell_visits(p[:-2, i]) for i in range(3)], axis=0)
    basis = RbfBasis(grid.centers()[visits >= 50], grid.sigma)
    assert basis.size >= 4
    est = OnlineHerdEstimator(run.agents, run.dt, 'pairwise', GRID, BOUNDS, forgetting=1.0,
                              p0=1e10, basis=basis)
    for t, snap in zip(run.times, p):
        est.add_snapshot(t, snap)
    for i in range(3):
        batch = fit_agent(agent_regression([p], i, basis, run.dt, run.agents))
        rel = np.linalg.norm(est.theta[i] - batch.theta) / np.linalg.norm(batch.theta)
        assert rel < 1e-6, (i, rel)
        assert est.samples[i] == batch.n_samples
        # P ≈ (ΦᵀΦ)⁻¹: the RLS standard errors agree with the textbook OLS ones
        ols = fit_agent(agent_regression([p], i, basis, run.dt, run.agents), se='ols')
        se = est.rls.theta_se()[i]
        # (P is the final one, σ̂² is exact: see below; p0 = 1e10 leaves a tiny prior)
        assert np.allclose(se, ols.theta_se, rtol=0.01), np.max(np.abs(se / ols.theta_se - 1))
        # Σ εᵀε of the standardized innovations is the batch residual sum of squares
        rss = float((ols.residuals ** 2).sum())
        assert np.isclose(np.trace(est.rls.sq_residual[i]), rss, rtol=1e-6)


STEP_GRID = (3, 3)  # a coarser field (p = 23): a short memory estimates fewer parameters


def _damping_step_data(steps_before=3000, steps_after=3000):
    truth = make_truth_model(3, seed=11, grid=STEP_GRID, bounds=BOUNDS)
    truth.damping[0] = 0.95
    first = simulate(truth, steps_before, initial_positions(truth, seed=11, spread=25), seed=1)
    p = first.positions
    truth.damping[0] = 0.80
    second = simulate(truth, steps_after + 1, p[-1], (p[-1] - p[-2]) / truth.dt, seed=2,
                      t0=first.times[-1])
    return first.agents, np.concatenate([p, second.positions[1:]])


def test_forgetting_tracks_a_step_change_of_damping():
    agents, p = _damping_step_data()
    change = 3000  # first snapshot simulated with the new damping
    took = {}
    for lam in (0.95, 1.0):
        est = OnlineHerdEstimator(agents, 1.0, 'pairwise', STEP_GRID, BOUNDS, forgetting=lam,
                                  p0=1e4)
        a = np.empty(len(p))
        for k, snap in enumerate(p):
            est.add_snapshot(float(k), snap)
            a[k] = est.theta[0, 0]
        assert abs(np.median(a[change - 500:change]) - 0.95) < 0.05, lam
        near = np.abs(a[change:] - 0.80) < 0.03
        took[lam] = int(np.argmax(near)) if near.any() else None
    print(f'\nstep change of damping 0.95 -> 0.80 (directional forgetting): |â − 0.80| < 0.03 '
          f'after {took[0.95]} steps with λ = 0.95; with λ = 1: {took[1.0]}')
    assert took[0.95] is not None and took[0.95] < 1500
    assert took[1.0] is None  # without forgetting the old regime holds on for 3000 steps


def test_covariance_stays_bounded_without_excitation_100k_steps():
    rng = np.random.default_rng(0)
    n, p, steps = 4, 5, 100_000
    truth = rng.normal(size=(n, p))
    directional = HerdRLS(n, p, forgetting=0.95, p0=10.0)
    exponential = HerdRLS(n, p, forgetting=0.95, p0=10.0, windup='exponential')
    H = np.zeros((n, 2, p))
    for k in range(steps):
        H[:, :, :3] = rng.normal(size=(n, 2, 3))     # directions 3 and 4 are never excited
        y = np.einsum('nkp,np->nk', H, truth) + 0.01 * rng.normal(size=(n, 2))
        directional.update(H, y)
        if k < 300:
            exponential.update(H, y)
    P = directional.P
    eig = np.linalg.eigvalsh(P)
    assert np.allclose(P, np.swapaxes(P, 1, 2))
    assert eig.min() > 0 and eig.max() <= 10.0 * (1 + 1e-9)   # never above P₀
    assert np.allclose(P[:, 3:, 3:], 10.0 * np.eye(2))        # unexcited block keeps its prior
    assert np.allclose(directional.theta[:, :3], truth[:, :3], atol=0.01)
    # plain exponential forgetting winds up: P grows like λ^-t in the unexcited directions
    assert exponential.P[:, 4, 4].min() > 10.0 * 0.95 ** -300 * 0.99


def test_masked_and_non_finite_agents_are_skipped():
    rng = np.random.default_rng(1)
    n, p = 3, 4
    rls = HerdRLS(n, p, forgetting=0.98, p0=100.0)
    for _ in range(50):
        H = rng.normal(size=(n, 2, p))
        rls.update(H, rng.normal(size=(n, 2)))
    theta, P, samples = rls.theta.copy(), rls.P.copy(), rls.samples.copy()
    H = rng.normal(size=(n, 2, p))
    y = rng.normal(size=(n, 2))
    y[2] = np.nan                                   # agent 2: stale snapshot
    e = rls.update(H * 1e6, y * 1e6, mask=[False, True, True])  # agent 0: masked, absurd data
    assert np.isnan(e[0]).all() and np.isnan(e[2]).all() and np.isfinite(e[1]).all()
    for i in (0, 2):
        assert np.array_equal(rls.theta[i], theta[i]) and np.array_equal(rls.P[i], P[i])
        assert rls.samples[i] == samples[i]
    assert rls.samples[1] == samples[1] + 1


def test_missing_agent_in_a_snapshot_never_poisons_theta():
    truth, run = recovery_run(3, 5, 1500)
    p = run.positions.copy()
    p[700:705, 1] = np.nan                           # agent 2 drops out for five snapshots
    clean = online_fit([run], grid=GRID, bounds=BOUNDS).estimator
    est = OnlineHerdEstimator(run.agents, 1.0, 'pairwise', GRID, BOUNDS)
    for t, snap in zip(run.times, p):
        est.add_snapshot(t, snap)
    assert np.isfinite(est.theta).all()
    # a missing neighbour drops out of the others' sums (they keep learning); agent 2
    # lacks p^τ at τ = 700..704 and its own u^τ or u^{τ+1} at τ = 698, 699
    assert list(clean.samples - est.samples) == [0, 7, 0]
    assert np.allclose(est.theta[:, 0], clean.theta[:, 0], atol=0.01)


@pytest.mark.parametrize('forgetting, windup', [(0.97, 'directional'), (0.97, 'exponential'),
                                                (1.0, 'directional')])
def test_compiled_kernel_equals_numpy_path(forgetting, windup):
    """The numba kernel (rls_kernels) and the numpy path evaluate the same equations: equal
    to rounding (~1e-13 relative after 40 updates, bound 1e-10), same skipped agents, P
    symmetric to the last bit."""
    pytest.importorskip('numba')
    from herd_ros.estimation import rls_kernels
    assert rls_kernels.compiled_update() is not None
    rng = np.random.default_rng(7)
    n, p = 7, 13
    fast = HerdRLS(n, p, forgetting=forgetting, p0=1.0, windup=windup)
    slow = HerdRLS(n, p, forgetting=forgetting, p0=1.0, windup=windup, compiled=False)

    def rel(a, b):
        return np.abs(a - b).max() / np.abs(b).max()
    for k in range(40):
        H = rng.normal(size=(n, 2, p))
        if k % 2:
            H[:, :, -2:] = 0.0                       # two directions excited half the time
        y = rng.normal(size=(n, 2))
        if k == 5:
            y[3, 1] = np.nan                         # non-finite rows are skipped
            H[4, 0, 2] = np.inf
        mask = rng.random(n) > 0.2
        e_fast, e_slow = fast.update(H, y, mask), slow.update(H, y, mask)
        assert np.array_equal(np.isnan(e_fast), np.isnan(e_slow))
        used = np.isfinite(e_slow).all(axis=1)
        assert rel(e_fast[used], e_slow[used]) < 1e-10
    assert rel(fast.P, slow.P) < 1e-10
    assert rel(fast.theta, slow.theta) < 1e-10
    assert rel(fast.sq_residual, slow.sq_residual) < 1e-10
    assert np.array_equal(fast.samples, slow.samples) and fast.samples.min() < 40
    assert np.allclose(fast.weight, slow.weight, rtol=1e-14)
    assert np.array_equal(fast.P, np.swapaxes(fast.P, 1, 2))   # symmetric to the last bit


@pytest.mark.parametrize('compiled', [True, False])
def test_rank_deficient_rows_by_hand(compiled):
    """H = 0 for an agent (S₀ = 0: nothing to forget, nothing learned) leaves it unchanged;
    one non-zero row is a scalar RLS step. The pseudo-inverse of S₀ in directional
    forgetting must not divide by zero (both implementations)."""
    rls = HerdRLS(2, 3, forgetting=0.9, p0=4.0, compiled=compiled)
    H = np.zeros((2, 2, 3))
    H[1] = [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]        # agent 1: one row, one direction
    rls.update(H, np.array([[1.0, 1.0], [2.0, 0.5]]))
    assert np.array_equal(rls.P[0], 4.0 * np.eye(3)) and np.array_equal(rls.theta[0], np.zeros(3))
    # agent 1, direction 0, λ-forgetting then a scalar RLS step: p̄ = 4/0.9, p⁺ = p̄/(1 + p̄)
    pbar = 4.0 / 0.9
    assert np.isclose(rls.P[1, 0, 0], pbar / (1 + pbar), rtol=1e-12)
    assert np.isclose(rls.theta[1, 0], 2.0 * pbar / (1 + pbar), rtol=1e-12)
    assert np.allclose(rls.P[1, 1:, 1:], 4.0 * np.eye(2))


def test_prequential_skill_counts_the_predictions_made_before_each_update():
    """The running RMS of the estimator's own predictions, by hand: with λ = 1 and a huge
    p0, the first prediction of an agent (θ = 0) is stay-put exactly, so after one update
    model and stay-put errors are equal; constant velocity is Δt·(u^{τ+1} − u^τ)."""
    from herd_ros.estimation.online_fit import OnlineHerdEstimator
    est = OnlineHerdEstimator(['a', 'b'], 2.0, 'pairwise', (1, 1), (-10, 10, -10, 10))
    p = [np.array([[0.0, 0.0], [5.0, 5.0]]), np.array([[1.0, 0.0], [5.0, 6.0]]),
         np.array([[3.0, 1.0], [4.0, 6.0]])]
    for k, q in enumerate(p):
        est.add_snapshot(2.0 * k, q)
    sk = est.skill()
    u0, u1 = (p[1] - p[0]) / 2.0, (p[2] - p[1]) / 2.0
    stay = 2.0 * np.linalg.norm(u1, axis=1)
    cv = 2.0 * np.linalg.norm(u1 - u0, axis=1)
    np.testing.assert_allclose(sk['stay_put'], stay)
    np.testing.assert_allclose(sk['constant_velocity'], cv)
    np.testing.assert_allclose(sk['model'], stay)          # θ = 0 predicts stay-put
    assert sk['predictions'].tolist() == [1, 1]
    assert sk['stay_put_herd'] == pytest.approx(np.sqrt((stay ** 2).mean()))
