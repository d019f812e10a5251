"""Velocity memory κ: the damping of eq. 2 acting on ū ← (1 − κ) ū + κ u.

Checked against hand-computed sequences, a known-truth herd simulated with κ = 0.35 (the
selection must find it, and the fit recover the damping), Monte Carlo for the k-step
covariance, and the follower's discrete law at α = 1.
"""
import numpy as np
import pytest

from herd_ros.control.herd_follower import HerdFollower
from herd_ros.errors import HerdInputError
from herd_ros.estimation.herd_fit import fit_structure
from herd_ros.estimation.model_selection import select_model
from herd_ros.model.herd_model import AgentLaw, HerdModel
from herd_ros.model.model_file import load_model, save_model
from herd_ros.model.rbf_field import RbfBasis
from herd_ros.model.velocity_memory import memory_velocities
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.simulation.prediction import predict_ahead, prediction_covariance


def damping_model(damping, memory, q=0.04, dt=1.0):
    """A damping-only herd (no interactions, zero field) with velocity memory ``memory``."""
    agents = [f'a{k}' for k in range(len(damping))]
    basis = RbfBasis(np.zeros((1, 2)), np.ones(1))
    laws = {a: AgentLaw(damping=d, neighbors=[b for b in agents if b != a],
                        theta1=np.zeros(len(agents) - 1), theta2=np.zeros(len(agents) - 1),
                        basis=basis, field_u=[0.0], field_v=[0.0], noise_cov=q * np.eye(2))
            for a, d in zip(agents, damping)}
    return HerdModel(agents=agents, dt=dt, laws=laws, meta={'velocity_memory': memory})


def test_memory_velocities_by_hand():
    u = np.array([[1., 0], [3, 2], [np.nan, np.nan], [2, 2], [4, 0]])[:, None, :]
    # κ = 0.5: 1,0 -> 0.5·(1,0) + 0.5·(3,2) = (2,1); a gap restarts the mean at (2,2)
    want = np.array([[1, 0], [2, 1], [np.nan, np.nan], [2, 2], [3, 1]])
    np.testing.assert_allclose(memory_velocities(u, 0.5)[:, 0], want)
    assert memory_velocities(u, 1.0) is u            # the paper's model, untouched
    for bad in (0.0, 1.5, -0.2):
        with pytest.raises(HerdInputError, match='velocity memory'):
            memory_velocities(u, bad)


def test_one_step_prediction_by_hand():
    """p̂^{τ+2} = p^{τ+1} + Δt a ū^τ, ū^τ = (1 − κ) ū^{τ−1} + κ u^τ."""
    m = damping_model([0.5, 0.5], 0.25, dt=2.0)
    x = np.array([0.0, 2.0, 6.0, 8.0])           # u = 1, 2, 1 m/s
    p = np.zeros((4, 2, 2))
    p[:, :, 0] = x[:, None]
    ubar0, ubar1 = 1.0, 0.75 * 1.0 + 0.25 * 2.0   # 1, 1.25
    want = [2.0 + 2.0 * 0.5 * ubar0, 6.0 + 2.0 * 0.5 * ubar1]
    np.testing.assert_allclose(m.predict_one_step(p)[:, 0, 0], want)
    np.testing.assert_allclose(predict_ahead(m, p, 1)[2:, 0, 0], want)


def _truth_run(memory, steps=12000, seed=3):
    truth = damping_model([0.8, 0.7, 0.75, 0.85], memory, q=0.02)
    start = np.array([[0., 0], [30, 0], [0, 30], [30, 30]])
    return truth, simulate(truth, steps, start, seed=seed)


def test_selection_finds_and_fit_recovers_the_memory():
    truth, run = _truth_run(0.35)
    sel = select_model([run.positions], list(run.agents), run.dt, grids=[])
    assert sel.chosen.memory == 0.35
    assert not sel.chosen.interactions
    fit = fit_structure([run], sel.chosen)
    assert (fit.model.velocity_memory == 0.35).all()
    a, se = fit.model.damping, np.array([f.theta_se[0] for f in fit.fits.values()])
    assert np.all(np.abs(a - truth.damping) < 3 * se), (a, se)


def test_selection_keeps_the_papers_velocity_without_memory():
    _, run = _truth_run(1.0)
    sel = select_model([run.positions], list(run.agents), run.dt, grids=[])
    assert sel.chosen.memory == 1.0


def test_k_step_covariance_matches_monte_carlo():
    """prediction_covariance's impulse response against 4000 simulated futures."""
    m = damping_model([0.6, 0.6], 0.3, q=0.05)
    k, n = 5, 4000
    rng = np.random.default_rng(0)
    # the deterministic prediction from ū = u = 0 at p = 0 is 0; the error is the noise's
    ends = []
    for _ in range(n):
        u = np.zeros(2)
        ubar = np.zeros(2)
        p = np.zeros(2)
        for _ in range(k):
            u = 0.6 * ubar + rng.normal(0, np.sqrt(0.05), 2)
            p = p + u
            ubar = 0.7 * ubar + 0.3 * u
        ends.append(p)
    emp = np.cov(np.array(ends).T)
    cov = prediction_covariance(m, k)[0]
    np.testing.assert_allclose(np.diag(cov), np.diag(emp), rtol=0.08)


def test_follower_steps_the_discrete_law():
    """At α = 1 a tick of the follower is one step of eq. 2 with memory (robot 1 on an
    animal with κ = 0.4, robot 2 on one with κ = 1)."""
    m = damping_model([0.5, 0.5], [0.4, 1.0], q=0.0)
    f = HerdFollower(m, ['a0', 'a1'])
    far = np.array([[0.0, 0.0], [1e4, 0.0]])
    u = np.array([[1.0, 0.0], [0.0, 2.0]])
    ubar = u.copy()
    kappa = np.array([[0.4], [1.0]])
    for _ in range(4):
        want = 0.5 * ubar                      # u^{τ+1} = a ū^τ (no drift)
        u = f.advance(u, far, elapsed=1.0)
        np.testing.assert_allclose(u, want, atol=1e-12)
        ubar = (1 - kappa) * ubar + kappa * u


def test_model_file_round_trip_and_bad_value(tmp_path):
    m = damping_model([0.5, 0.4], 0.35)
    path = save_model(m, tmp_path / 'm.yaml')
    assert 'velocity_memory: 0.35' in path.read_text()
    assert (load_model(path).velocity_memory == 0.35).all()
    plain = save_model(damping_model([0.5, 0.4], 1.0), tmp_path / 'p.yaml')
    assert 'velocity_memory' not in plain.read_text()
    assert (load_model(plain).velocity_memory == 1.0).all()
    path.write_text(path.read_text().replace('velocity_memory: 0.35', 'velocity_memory: 1.5'))
    with pytest.raises(HerdInputError, match='velocity_memory|velocity memory'):
        load_model(path)


def test_simulated_velocity_autocorrelation_matches_theory():
    """Lag-5 autocorrelation of a simulated velocity against its closed form.

    κ = 1: u is AR(1) with a = 0.6, ρ5 = a⁵ = 0.078. κ = 0.3: ū is AR(1) with
    φ = 1 − κ + κa = 0.88 and innovation κw, u^{τ+1} = a ū^τ + w, so with σ² = Var(w):
    Var ū = κ²σ²/(1 − φ²), Var u = a² Var ū + σ²,
    Cov(u^τ, u^{τ+5}) = a² φ⁵ Var ū + a κ φ⁴ σ²   -> ρ5 = 0.161.
    """
    a, kappa = 0.6, 0.3
    phi = 1 - kappa + kappa * a
    var_m = kappa ** 2 / (1 - phi ** 2)
    want = {1.0: a ** 5,
            kappa: (a ** 2 * phi ** 5 * var_m + a * kappa * phi ** 4) / (a ** 2 * var_m + 1)}
    for k, rho in want.items():
        m = damping_model([a], k, q=0.05)
        run = simulate(m, 40000, np.zeros((1, 2)), seed=1)
        u = np.diff(run.positions[:, 0, 0])
        got = np.corrcoef(u[:-5], u[5:])[0, 1]
        assert abs(got - rho) < 0.025, (k, got, rho)
    assert want[kappa] > 2 * want[1.0]       # memory keeps the heading longer


def test_memory_candidates_cross_validation_equals_brute_force():
    """The memory candidates' CV RMS (formed from the κ = 1 statistics by replacing the
    damping column) against refits done the long way: ū by a plain loop restarted in
    every block, a = Σ ū·u' / Σ |ū|² on the other blocks."""
    _, run = _truth_run(0.35, steps=1500)
    agents, dt, folds = list(run.agents), run.dt, 4
    sel = select_model([run.positions], agents, dt, folds=folds, grids=[], terms=['damping'])
    rows = {r['structure'].memory: r['rms'] for r in sel.table
            if not isinstance(r['structure'].memory, tuple)}       # herd-wide κ
    assert sorted(rows) == [0.2, 0.35, 0.6, 1.0]
    edges = np.linspace(0, run.n_steps - 2, folds + 1).astype(int)
    for kappa, got in rows.items():
        sse = n = 0.0
        for i in range(len(agents)):
            blocks = []
            for b0, b1 in zip(edges[:-1], edges[1:]):
                u = np.diff(run.positions[b0:b1 + 2, i], axis=0) / dt
                ubar = [u[0]]
                for t in range(1, len(u)):
                    ubar.append((1 - kappa) * ubar[-1] + kappa * u[t])
                blocks.append((np.array(ubar[:-1]), u[1:]))
            for b in range(folds):
                x = np.concatenate([blocks[k][0] for k in range(folds) if k != b])
                y = np.concatenate([blocks[k][1] for k in range(folds) if k != b])
                a = (x * y).sum() / (x * x).sum()
                xb, yb = blocks[b]
                sse += ((a * xb - yb) ** 2).sum()
                n += len(yb)
        assert got == pytest.approx(dt * np.sqrt(sse / n), rel=1e-9), kappa


def test_one_memory_per_agent_is_selected_recovered_and_saved(tmp_path):
    """Two agents with κ = 0.3 and two with κ = 1: the selection keeps one κ per agent,
    the right one for each, and the model file carries them in agents order."""
    truth = damping_model([0.8, 0.7, 0.75, 0.85], [0.3, 1.0, 0.3, 1.0], q=0.02)
    start = np.array([[0., 0], [30, 0], [0, 30], [30, 30]])
    run = simulate(truth, 12000, start, seed=5)
    sel = select_model([run.positions], list(run.agents), run.dt, grids=[])
    assert sel.chosen.memory == (0.35, 1.0, 0.35, 1.0), sel.chosen.label()
    fit = fit_structure([run], sel.chosen)
    path = save_model(fit.model, tmp_path / 'm.yaml')
    np.testing.assert_array_equal(load_model(path).velocity_memory, [0.35, 1.0, 0.35, 1.0])


def test_a_forced_memory_leaves_the_naive_baselines_alone():
    """Constant velocity and stay-put do not depend on the model's memory."""
    _, run = _truth_run(0.35, steps=3000)
    auto = select_model([run.positions], list(run.agents), run.dt, grids=[])
    forced = select_model([run.positions], list(run.agents), run.dt, grids=[], memory=0.35,
                          memories=())
    assert forced.chosen.memory == 0.35
    for name, value in auto.baselines.items():
        assert forced.baselines[name] == pytest.approx(value, rel=1e-12), name
