"""Acceptance of the offline method on herds with known truth (issue: batch identification).

Truth: `make_truth_model` (damping 0.90–0.97, pairwise θ1/θ2 with equilibrium spacing
10–50 m, a circulating non-gradient field on the same 6x6 grid the fit is given, process
noise only). Every expectation compares with the known parameters, never with a refit.
"""
import numpy as np
import pytest

from herd_ros.estimation.herd_fit import fit_herd, split_runs
from herd_ros.estimation.whiteness import whiteness
from herd_ros.model.model_file import load_model, save_model
from herd_ros.simulation.herd_simulator import simulate, simulate_from
from herd_ros.simulation.prediction import one_step_rms
from herd_ros.simulation.statistics import herd_statistics
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model

BOUNDS = (-75.0, 75.0, -75.0, 75.0)
GRID = (6, 6)


def herd(n, seed, steps):
    truth = make_truth_model(n, seed=seed, grid=GRID, bounds=BOUNDS)
    run = simulate(truth, steps, initial_positions(truth, seed=seed, spread=25), seed=seed + 1000)
    return truth, run


def true_theta_on(fitted_law, true_law):
    """The truth's θ restricted to the centres the fit kept (same grid => same centres)."""
    keep = [int(np.argmin(((true_law.basis.centers - c) ** 2).sum(1)))
            for c in fitted_law.basis.centers]
    assert np.allclose(true_law.basis.centers[keep], fitted_law.basis.centers)
    return np.concatenate([[true_law.damping], true_law.theta1, true_law.theta2,
                           true_law.field_u[keep], true_law.field_v[keep]])


@pytest.mark.slow
@pytest.mark.parametrize('n_agents,steps', [(3, 20000), (10, 6000)])
def test_standard_errors_are_honest_over_10_seeds(n_agents, steps):
    """Mean z² of every θ over 10 independent herds (≥ 1 700 z-values per case)."""
    ratios = []
    for seed in range(10):
        truth, run = herd(n_agents, seed, steps)
        fit = fit_herd([run], grid=GRID, bounds=BOUNDS)
        for a in truth.agents:
            law = fit.model.laws[a]
            z = (law.theta - true_theta_on(law, truth.laws[a])) / law.theta_se
            ratios.append(z ** 2)
    mean_ratio = float(np.mean(np.concatenate(ratios)))
    assert 0.5 <= mean_ratio <= 3.0, mean_ratio


@pytest.mark.slow
@pytest.mark.parametrize('n_agents', [3, 10])
def test_damping_and_held_out_prediction(n_agents):
    truth, run = herd(n_agents, 7, 25000)
    train, test = split_runs([run], 0.8)  # 20 000 training steps
    fit = fit_herd(train, grid=GRID, bounds=BOUNDS)
    for a in truth.agents:
        rel = abs(fit.model.laws[a].damping - truth.laws[a].damping) / truth.laws[a].damping
        assert rel < 0.01, (a, rel)
    fitted = one_step_rms(fit.model, test)['model']['herd']
    true = one_step_rms(truth, test)['model']['herd']
    assert fitted <= 1.05 * true, (fitted, true)


def _curve_and_field_errors(truth, fit, run):
    p = run.positions
    f_err, g_err = [], []
    for i, a in enumerate(truth.agents):
        tl, fl = truth.laws[a], fit.model.laws[a]
        for k, b in enumerate(tl.neighbors):
            j = truth.agents.index(b)
            d = np.linalg.norm(p[:, j] - p[:, i], axis=1)
            dd = np.linspace(*np.percentile(d, [5, 95]), 50)
            f_err.append(np.sqrt(np.mean(((tl.theta1[k] - tl.theta2[k] / dd)
                                          - (fl.theta1[k] - fl.theta2[k] / dd)) ** 2)))
        pts = p[:, i]
        gt = tl.basis.features(pts)
        gf = fl.basis.features(pts)
        err = np.hypot(gt @ tl.field_u - gf @ fl.field_u, gt @ tl.field_v - gf @ fl.field_v)
        g_err.append(np.sqrt(np.mean(err ** 2)))
    return np.mean(f_err), np.mean(g_err)


@pytest.mark.slow
def test_force_curves_and_field_converge_with_data():
    short, long_ = [], []
    for seed in (11, 12, 13):
        truth, run = herd(3, seed, 30000)
        for steps, out in ((3000, short), (30000, long_)):
            part = run.slice(0, steps)
            out.append(_curve_and_field_errors(truth, fit_herd([part], grid=GRID,
                                                                bounds=BOUNDS), part))
    short, long_ = np.array(short), np.array(long_)
    assert (long_[:, 0] < short[:, 0]).all(), (short, long_)   # F_ij(d)
    assert (long_[:, 1] < short[:, 1]).all(), (short, long_)   # g_i on visited points
    assert long_.mean(0)[0] < 0.6 * short.mean(0)[0]
    assert long_.mean(0)[1] < 0.6 * short.mean(0)[1]


@pytest.mark.slow
def test_residual_white_velocity_not():
    truth, run = herd(3, 21, 20000)
    fit = fit_herd([run], grid=GRID, bounds=BOUNDS)
    res = fit.model.residuals(run.positions)
    vel = np.diff(run.positions, axis=0)
    for i, a in enumerate(truth.agents):
        wr, wv = whiteness(res[:, i]), whiteness(vel[:, i])
        assert wr.inside_90 >= 0.85, (a, wr.inside_90)
        assert wv.inside_90 <= 0.50, (a, wv.inside_90)
        assert wr.ljung_box * 100 <= wv.ljung_box, (a, wr.ljung_box, wv.ljung_box)


def test_model_file_round_trip_reproduces_predictions(tmp_path):
    truth, run = herd(3, 31, 4000)
    fit = fit_herd([run], grid=GRID, bounds=BOUNDS)
    path = save_model(fit.model, tmp_path / 'model.yaml')
    loaded = load_model(path)
    np.testing.assert_array_equal(loaded.predict_one_step(run.positions),
                                  fit.model.predict_one_step(run.positions))
    for a in truth.agents:
        np.testing.assert_array_equal(loaded.laws[a].theta, fit.model.laws[a].theta)
        np.testing.assert_array_equal(loaded.laws[a].theta_se, fit.model.laws[a].theta_se)
        np.testing.assert_array_equal(loaded.laws[a].noise_cov, fit.model.laws[a].noise_cov)


@pytest.mark.slow
def test_simulated_statistics_match_the_data():
    truth, run = herd(3, 41, 20000)
    fit = fit_herd([run], grid=GRID, bounds=BOUNDS)
    real = herd_statistics(run)
    sims = [simulate_from(fit.model, run, seed=s) for s in range(3)]
    sim = herd_statistics(sims)
    for a in truth.agents:
        for key in real[a]:
            rel = abs(sim[a][key] - real[a][key]) / real[a][key]
            assert rel <= 0.20, (a, key, real[a][key], sim[a][key])
