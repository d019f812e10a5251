"""How much of the residual the herd shares (herd_ros.estimation.shared_residuals, (C1)-(C2)):
against noise drawn with a known common component, and hand-computed cases."""
import numpy as np
import pytest

from herd_ros.estimation.shared_residuals import (common_component_correlation,
                                                  format_shared_residuals, shared_correlation,
                                                  shared_residuals)


def herd_noise(steps, agents, rho, phi, seed=0):
    """w_i = √(1−ρ) ξ_i + √ρ c with c a unit-variance AR(1) of coefficient φ, per axis."""
    rng = np.random.default_rng(seed)
    c = np.empty((steps, 2))
    c[0] = rng.standard_normal(2)
    e = rng.standard_normal((steps, 2))
    for t in range(1, steps):
        c[t] = phi * c[t - 1] + np.sqrt(1 - phi ** 2) * e[t]
    own = rng.standard_normal((steps, agents, 2))
    scale = rng.uniform(0.5, 3.0, size=(1, agents, 1))          # animals' own noise levels
    return scale * (np.sqrt(1 - rho) * own + np.sqrt(rho) * c[:, None])


def test_closed_form_by_hand():
    # W = 1: the share itself; W = 2: S_2 = 2 + 2φ, r = ρ(1 + φ) / (1 + ρφ)
    assert common_component_correlation(0.3, 0.9, 1) == pytest.approx(0.3)
    assert common_component_correlation(0.1, 0.5, 2) == pytest.approx(0.1 * 1.5 / 1.05)
    # white common noise: the share at every window
    assert common_component_correlation(0.2, 0.0, 50) == pytest.approx(0.2)


def test_independent_animals_share_nothing():
    w = herd_noise(20_000, 12, rho=0.0, phi=0.0, seed=1)
    for window in (1, 10, 100, 500):
        value, blocks = shared_correlation(w, window)
        assert blocks == 20_000 // window
        assert abs(value) < 3.0 / np.sqrt(blocks)


def test_a_slow_common_component_is_recovered_at_every_window():
    rho, phi = 0.01, 0.98
    w = herd_noise(60_000, 15, rho, phi, seed=2)
    for window in (1, 20, 200, 1000):
        value, blocks = shared_correlation(w, window)
        expected = common_component_correlation(rho, phi, window)
        assert value == pytest.approx(expected, abs=max(0.2 * expected, 2.5 / np.sqrt(blocks)))
    # it rises with the window, as (C2) says
    assert shared_correlation(w, 1000)[0] > 5 * shared_correlation(w, 1)[0]


def test_one_herd_moving_as_one():
    w = herd_noise(5_000, 6, rho=1.0, phi=0.5, seed=3)
    assert shared_correlation(w, 1)[0] == pytest.approx(1.0)


def test_gaps_and_absent_animals_do_not_break_it():
    w = herd_noise(20_000, 8, rho=0.2, phi=0.0, seed=4)
    w[:, 0] = np.nan                                 # an animal never present
    w[5_000:7_000, 3] = np.nan                       # a collar silent for a while
    w[::17, 5, 1] = np.nan                           # scattered missing residuals
    value, _ = shared_correlation(w, 10)
    assert value == pytest.approx(0.2, abs=0.05)
    assert np.isnan(shared_correlation(w[:, :1], 10)[0])      # one animal: no pairs


def test_report_windows_runs_and_the_line():
    runs = [herd_noise(3_000, 5, rho=0.3, phi=0.9, seed=5), herd_noise(1_000, 5, 0.3, 0.9, 6)]
    out = shared_residuals(runs, dt=5.0)
    # one step (5 s), 1 min (12 steps: 333 blocks), 10 min (120 steps: 34 blocks);
    # 1 h (720 steps) has too few blocks
    assert out['window_s'] == [5.0, 60.0, 600.0]
    assert out['blocks'][0] == 4_000 + 2            # each run followed by a one-window gap
    assert out['correlation'][2] > out['correlation'][0] > 0.2
    line = format_shared_residuals(out)
    assert '5 s' in line and '10 min' in line and 'moves together' in line
    assert 'too few' in format_shared_residuals(shared_residuals([], dt=1.0))
