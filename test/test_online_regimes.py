"""Stop-and-go noise learned online (:mod:`herd_ros.estimation.online_regimes`): the
residual window, the regime fit of a herd simulated with known regimes, the message rows.
Expectations come from the simulated truth and hand-made arrays."""
import dataclasses

import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.estimation.online_fit import OnlineHerdEstimator
from herd_ros.estimation.online_regimes import (ResidualWindow, fit_residuals, pack_regimes,
                                                rank_one_factor, unpack_regimes)
from herd_ros.model.noise_regimes import (GaussianNoise, RegimeNoise, carry_regime_state,
                                          stationary_distribution)
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model

#: two regimes, resting (variance × 0.1) and moving (× 4), mean dwell 20 and 10 steps
TRANSITION = np.array([[0.95, 0.05], [0.10, 0.90]])
SCALES = (0.1, 4.0)


def test_the_window_keeps_the_last_rows_in_order_and_gaps_as_missing():
    w = ResidualWindow(2, 3)
    for k in range(4):
        w.push(np.full((2, 2), float(k)))
    w.push(None)                                   # a gap
    r = w.residuals()
    assert r.shape == (3, 2, 2)
    np.testing.assert_array_equal(r[:2, 0, 0], [2.0, 3.0])
    assert np.isnan(r[2]).all()
    np.testing.assert_array_equal(w.counts(), [2, 2])
    w.clear()
    assert w.residuals().shape == (0, 2, 2)
    with pytest.raises(HerdInputError):
        ResidualWindow(2, 0)


def test_a_rank_one_outer_product_gives_back_its_vector_up_to_sign():
    rng = np.random.default_rng(0)
    e = rng.standard_normal((50, 2))
    f = rank_one_factor(e[:, :, None] * e[:, None, :])
    np.testing.assert_allclose(f[:, :, None] * f[:, None, :], e[:, :, None] * e[:, None, :],
                               atol=1e-12)


def regime_truth(seed=3):
    truth = make_truth_model(3, seed=seed, grid=(6, 6), bounds=(-75.0, 75.0, -75.0, 75.0))
    q = np.asarray(truth.noise_cov)
    cov = np.stack([np.stack([s * q[i] for s in SCALES]) for i in range(3)])
    trans = np.repeat(TRANSITION[None], 3, axis=0)
    return dataclasses.replace(truth, meta={'noise_regimes': (cov, trans)}), cov


def feed(truth, steps, window, seed=5):
    run = simulate(truth, steps, initial_positions(truth, seed=1, spread=25), seed=seed)
    est = OnlineHerdEstimator(list(run.agents), 1.0, field_grid=(6, 6),
                              field_bounds=(-75.0, 75.0, -75.0, 75.0), regime_window=window)
    for t, p in zip(run.times, run.positions):
        est.add_snapshot(float(t), p)
    return est


def test_the_online_estimator_recovers_known_noise_regimes():
    truth, cov = regime_truth()
    est = feed(truth, 4000, window=3000)
    fit = est.refit_noise_regimes()
    assert fit is not None and fit['n_regimes'] >= 2, fit and fit['bic']
    got_cov, got_trans = est.noise_regimes
    pi = stationary_distribution(TRANSITION)
    for i in range(3):
        # the level of the noise (the standardized residuals are not inflated by the
        # parameters' uncertainty): the stationary mean within 10 % of the truth's
        mean_true = np.trace(np.einsum('k,kij->ij', pi, cov[i]))
        mean_got = np.trace(np.einsum('k,kij->ij', stationary_distribution(got_trans[i]),
                                      got_cov[i]))
        assert abs(mean_got / mean_true - 1) < 0.10, (i, mean_got, mean_true)
    # two regimes, as simulated: the loud one within 15 %, the quiet one well apart from it
    # (within 40 %: a tenth of the noise is where the law's small misfit shows), the dwell
    # of both as simulated
    two_cov, two_trans, _ = fit_residuals(est.residual_window.residuals(), counts=(2,))
    for i in range(3):
        ratio = np.trace(two_cov[i], axis1=1, axis2=2) / np.trace(cov[i], axis1=1, axis2=2)
        assert abs(ratio[1] - 1) < 0.15 and abs(ratio[0] - 1) < 0.4, (i, ratio)
        assert np.all(np.abs(np.diag(two_trans[i]) - np.diag(TRANSITION)) < 0.05)
    # the model of the estimator carries them, scaled to its Q_i
    model = est.model()
    cov_m, _ = model.meta['noise_regimes']
    for i in range(3):
        mean = np.einsum('k,kij->ij', stationary_distribution(got_trans[i]), cov_m[i])
        assert np.trace(mean) == pytest.approx(np.trace(model.noise_cov[i]), rel=1e-9)


def test_gaussian_noise_keeps_one_regime_and_too_few_residuals_fit_nothing():
    truth = make_truth_model(3, seed=3, grid=(6, 6), bounds=(-75.0, 75.0, -75.0, 75.0))
    est = feed(truth, 1500, window=1000)
    fit = est.refit_noise_regimes()
    assert fit['n_regimes'] == 1 and est.noise_regimes is None
    assert 'noise_regimes' not in (est.model().meta or {})
    assert feed(truth, 6, window=100).refit_noise_regimes() is None
    assert feed(truth, 50, window=0).refit_noise_regimes() is None     # no window kept


def test_the_message_rows_round_trip_and_bad_rows_are_refused():
    _, cov = regime_truth()
    trans = np.repeat(TRANSITION[None], 3, axis=0)
    rows = pack_regimes(cov, trans)
    assert rows.shape == (3, 2, 6)
    c, t = unpack_regimes(rows.ravel(), 3)
    np.testing.assert_allclose(c, cov)
    np.testing.assert_allclose(t, trans)
    with pytest.raises(HerdInputError, match='agents'):
        unpack_regimes(rows.ravel()[:-1], 3)
    bad = rows.copy()
    bad[0, 0, 4:] = [0.7, 0.7]                     # a transition row that sums to 1.4
    with pytest.raises(HerdInputError, match='probabilities'):
        unpack_regimes(bad, 3)


def test_a_new_noise_source_keeps_the_regimes_its_predecessor_was_in():
    _, cov = regime_truth()
    trans = np.repeat(TRANSITION[None], 3, axis=0)
    old = RegimeNoise(cov, trans, rng=1)
    old.state[:] = [1, 0, 1]
    new = RegimeNoise(cov, trans, rng=2)
    assert carry_regime_state(old, new)
    np.testing.assert_array_equal(new.state, [1, 0, 1])
    assert not carry_regime_state(GaussianNoise(cov[:, 0]), new)
    assert not carry_regime_state(old, RegimeNoise(cov[:2], trans[:2], rng=3))


def test_a_window_too_short_for_any_fit_is_refused_at_start():
    from herd_ros.params import ParameterError
    from herd_ros.params.estimator import PARAMS, check
    values = {name: spec.default for name, spec in PARAMS.items()}
    values.update(agents=['a', 'b'], dt=5.0)
    assert check(dict(values, regime_window=0))['regime_window'] == 0
    assert check(dict(values, regime_window=240))['regime_window'] == 240
    with pytest.raises(ParameterError, match='regime_window must be 0'):
        check(dict(values, regime_window=50))
