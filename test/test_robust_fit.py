"""Outlier-robust estimation (issue: predictions that beat naive baselines, acceptance 3).

A burst of 10 positions 1 km off in the training data must change no parameter of the
robust fit by more than its standard error, batch and online; plain least squares, on the
same data, is moved (so the check has teeth). Expectations: the clean fit's own θ and SE on
a known-truth herd, and hand-computed weights.
"""
import numpy as np
import pytest

from herd_ros.estimation.herd_fit import fit_structure
from herd_ros.estimation.model_selection import Structure
from herd_ros.estimation.online_fit import online_fit
from herd_ros.estimation.robust import OUTLIER_CHI2, outlier_weight
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model
from herd_ros.trajectory import HerdTrajectory

BOUNDS = (-75.0, 75.0, -75.0, 75.0)
FULL = Structure(True, (4, 4), 0.0)


def test_outlier_weights_by_hand():
    c = OUTLIER_CHI2
    np.testing.assert_allclose(outlier_weight([0.0, c, 2 * c, 10 * c, np.nan, np.inf]),
                               [1.0, 1.0, 0.5, 0.1, 0.0, 0.0])


@pytest.fixture(scope='module')
def clean_and_burst():
    truth = make_truth_model(3, seed=4, grid=(4, 4), bounds=BOUNDS)
    run = simulate(truth, 6000, initial_positions(truth, seed=4, spread=25), seed=5)
    p = run.positions.copy()
    p[3000:3010, 1] += [1000.0, 0.0]              # 10 positions of agent_2, 1 km east
    return run, HerdTrajectory(run.times, list(run.agents), p)


def _shift(model, ref):
    """max over agents and parameters of |θ − θ_ref| / SE_ref."""
    return max(float(np.max(np.abs(model.laws[a].theta - ref.laws[a].theta)
                            / ref.laws[a].theta_se)) for a in ref.agents)


def test_a_burst_moves_no_parameter_of_the_robust_batch_fit(clean_and_burst):
    clean, burst = clean_and_burst
    ref = fit_structure([clean], FULL, bounds=BOUNDS, robust=True).model
    rob = fit_structure([burst], FULL, bounds=BOUNDS, robust=True).model
    assert _shift(rob, ref) <= 1.0, _shift(rob, ref)
    # least squares is dragged by the same burst
    plain = fit_structure([burst], FULL, bounds=BOUNDS).model
    plain_ref = fit_structure([clean], FULL, bounds=BOUNDS).model
    assert _shift(plain, plain_ref) > 3.0, _shift(plain, plain_ref)
    # and on clean data the robust fit agrees with least squares within its errors
    assert _shift(ref, plain_ref) < 1.0, _shift(ref, plain_ref)
    np.testing.assert_allclose(rob.noise_cov, ref.noise_cov, rtol=0.05)


def test_a_burst_moves_no_parameter_of_the_robust_online_fit(clean_and_burst):
    clean, burst = clean_and_burst

    def final(run, robust):
        est = online_fit([run], grid=(4, 4), bounds=BOUNDS, min_visits=1,
                         robust=robust).estimator
        return est.rls.theta.copy(), est.rls.theta_se().copy()

    th_ref, se_ref = final(clean, True)
    th_rob, _ = final(burst, True)
    assert (np.abs(th_rob - th_ref) / se_ref).max() <= 1.0
    th_plain_ref, se_plain = final(clean, False)
    th_plain, _ = final(burst, False)
    assert (np.abs(th_plain - th_plain_ref) / se_plain).max() > 3.0
