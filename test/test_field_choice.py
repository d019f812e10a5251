"""The field a law gets, judged by its free run (issue 30): the error measure by hand, and a
known-truth herd keeps its fitted (true) field."""
import math

import pytest

from herd_ros.estimation.field_choice import (CLEAR_FAILURE, ValidationTail, choose_space_use,
                                             free_run_error)
from herd_ros.estimation.herd_fit import fit_herd
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model


def _result(distance, spread, pace):
    row = lambda ratio: {'median': ratio, 'data': 1.0}          # noqa: E731
    return {'herd': {'distance': row(distance), 'spread': row(spread), 'pace': row(pace)}}


def test_free_run_error_is_the_worst_log_ratio():
    assert free_run_error(_result(1.0, 1.0, 1.0)) == 0.0
    assert free_run_error(_result(2.0, 0.8, 1.1)) == pytest.approx(math.log(2.0))
    assert free_run_error(_result(1.2, 0.25, 1.0)) == pytest.approx(math.log(4.0))
    assert free_run_error(_result(1.0, 0.0, 1.0)) == math.inf
    assert CLEAR_FAILURE == pytest.approx(math.log(1.5))


def test_a_known_truth_herd_keeps_its_fitted_field():
    truth = make_truth_model(3, seed=1, grid=(4, 4), bounds=(-75, 75, -75, 75))
    run = simulate(truth, 4000, initial_positions(truth, seed=1, spread=25), seed=2)
    keep, figures = choose_space_use(ValidationTail(
        [run], lambda runs: fit_herd(runs, grid=(4, 4), bounds=(-75, 75, -75, 75)).model))
    assert not keep, figures
    assert figures['fitted']['free_run_error'] < CLEAR_FAILURE


def test_a_gaussian_known_truth_keeps_gaussian_noise():
    from herd_ros.estimation.field_choice import choose_noise_regimes
    truth = make_truth_model(3, seed=1, grid=(4, 4), bounds=(-75, 75, -75, 75))
    run = simulate(truth, 4000, initial_positions(truth, seed=1, spread=25), seed=2)
    keep, figures = choose_noise_regimes(ValidationTail(
        [run], lambda runs: fit_herd(runs, grid=(4, 4), bounds=(-75, 75, -75, 75)).model),
        space_use=False)
    assert not keep and figures.get('regimes', 1) == 1, figures


def test_a_choice_whose_free_run_error_has_no_value_says_so():
    """A tail on which a statistic is zero (one agent: no distance to others) gives a free-run
    error of inf; the fit's line says n/a and why, never 'inf'."""
    from herd_ros.estimation.field_choice import describe_choice, free_run_error
    flat = {'herd': {k: {'median': 0.0, 'data': 0.0} for k in
                     ('mean_distance', 'distance_spread', 'pace')}}
    err = free_run_error(flat, ('mean_distance',))
    assert err == float('inf')
    line = describe_choice('field', {'kept': False,
                                     'fitted': {'free_run_error': err, 'one_step': 0.5},
                                     'space_use': {'free_run_error': 0.25, 'one_step': 0.52}})
    assert 'inf' not in line and 'n/a' in line and '0.25' in line, line
    assert 'zero or undefined' in line
