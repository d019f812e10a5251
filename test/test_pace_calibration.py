"""The free-run noise calibrated to each animal's pace (issue 30: process noise apart from
measurement noise), against known truths: the true law needs no correction, a law whose
noise is twice the truth's is brought back to it, and the factor reaches every free
simulation (noise sources, robots, the model file)."""
import dataclasses

import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.herd_dynamics import FitOptions
from herd_ros.model.model_file import model_from_dict, model_to_dict
from herd_ros.model.noise_regimes import noise_for, subset_regimes
from herd_ros.simulation.free_run import shape_and_pace
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.simulation.pace_calibration import (calibrate_noise_scale, segment_starts,
                                                  with_noise_scale)
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model


#: a herd whose pace its noise sets: damped velocities, a weak pull home, no swirl
NOISY = dict(swirl=0.0, pull=0.003, damping_range=(0.8, 0.9))


@pytest.fixture(scope='module')
def truth_run():
    truth = make_truth_model(3, seed=1, noise_std=0.05, **NOISY)
    run = simulate(truth, 20000, initial_positions(truth, seed=1, spread=25), seed=3)
    return truth, run.positions


@pytest.mark.parametrize('kind', ['noise-driven', 'field-driven'])
def test_the_true_law_keeps_its_noise(truth_run, kind):
    if kind == 'noise-driven':
        truth, positions = truth_run
    else:       # the circulating field sets the pace; the noise barely moves it
        truth = make_truth_model(3, seed=1, noise_std=0.05)
        positions = simulate(truth, 6000, initial_positions(truth, seed=1, spread=25),
                             seed=3).positions
    cal = calibrate_noise_scale(truth, [positions])
    assert np.all((cal['scale'] > 0.8) & (cal['scale'] < 1.25)), (cal['scale'], cal['reason'])


def test_a_law_with_twice_the_noise_is_brought_back(truth_run):
    truth, positions = truth_run
    # the same law (same seed) whose residuals would carry a collar's error: std × 2
    inflated = make_truth_model(3, seed=1, noise_std=0.10, **NOISY)
    cal = calibrate_noise_scale(inflated, [positions])
    assert np.all(np.abs(cal['scale'] - 0.5) < 0.125), cal['scale']
    # the calibrated runs keep the pace the data have, the uncalibrated ones do not
    assert np.all(np.abs(cal['sim_pace'] / cal['data_pace'] - 1) < 0.1)
    assert np.all(cal['uncalibrated_pace'] / cal['data_pace'] > 1.3)
    # an independent check: the calibrated law and the true law, run on other seeds (the same
    # for both), move at the same pace; the inflated law does not
    model = with_noise_scale(inflated, cal['scale'])

    def pace(m):
        return np.mean([shape_and_pace(simulate(m, 20000, positions[0], seed=s).positions,
                                       1.0)['pace'] for s in (11, 12)], axis=0)
    assert np.all(np.abs(pace(model) / pace(truth) - 1) < 0.15)
    assert np.all(pace(inflated) / pace(truth) > 1.3)


def test_noise_sources_and_robots_carry_the_factor():
    truth = make_truth_model(2, seed=0, noise_std=0.2)
    model = with_noise_scale(truth, [0.5, 2.0])
    source = noise_for(model, 7)
    w = np.array([source.draw() for _ in range(20000)])             # (S, N, 2)
    assert w[:, 0].std() == pytest.approx(0.1, rel=0.05)
    assert w[:, 1].std() == pytest.approx(0.4, rel=0.05)
    # the robots of animal 1 only: its factor
    sub = subset_regimes(model.meta, [1])
    assert sub['noise_scale'].tolist() == [2.0]
    # the noise regimes are scaled too
    cov = np.repeat(np.eye(2)[None, None] * 0.04, 2, axis=0)         # (N=2, K=1, 2, 2)
    regimes = dict(model.meta, noise_regimes=(cov, np.ones((2, 1, 1))))
    source = noise_for(dataclasses.replace(model, meta=regimes), 1)
    w = np.array([source.draw() for _ in range(20000)])
    assert w[:, 1].std() == pytest.approx(0.4, rel=0.05)


def test_the_model_file_keeps_the_factors():
    truth = make_truth_model(2, seed=0)
    body = model_to_dict(with_noise_scale(truth, [0.25, 1.5]))
    assert body['noise_scale'] == [0.25, 1.5]
    back = model_from_dict(body)
    assert back.meta['noise_scale'].tolist() == [0.25, 1.5]
    for bad in ([0.5], [0.5, -1.0], ['a', 1.0]):
        with pytest.raises(HerdInputError, match='noise_scale'):
            model_from_dict(dict(body, noise_scale=bad))


def test_options_and_segments():
    assert FitOptions(noise_scale='0.5').noise_scale == 0.5
    for bad in ('x', '0', -1.0):
        with pytest.raises(HerdInputError, match='noise_scale'):
            FitOptions(noise_scale=bad)
    assert segment_starts(1000, 5000, 4) == [0]
    s = segment_starts(41000, 5000, 4)
    assert len(s) == 4 and s[0] == 0 and s[-1] == 36000
