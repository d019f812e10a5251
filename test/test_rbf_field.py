"""RBF grid, pruning and the boundedness of fitted fields away from the data."""
import numpy as np

from herd_ros.estimation.herd_fit import fit_herd
from herd_ros.model.rbf_field import FieldGrid, RbfBasis
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model


def test_grid_centres_and_sigma():
    g = FieldGrid(4, 2, (0.0, 40.0, 0.0, 20.0))
    c = g.centers()
    assert c.shape == (8, 2)
    np.testing.assert_allclose(sorted(set(c[:, 0])), [5, 15, 25, 35])
    np.testing.assert_allclose(sorted(set(c[:, 1])), [5, 15])
    assert np.isclose(g.sigma, 2 / 3 * 10)


def test_basis_value_is_normalised_gaussian():
    b = RbfBasis([[1.0, 2.0]], [3.0])
    p = np.array([[4.0, 6.0]])  # distance 5
    expected = np.exp(-25 / 18) / (3 * np.sqrt(2 * np.pi))
    assert np.isclose(b.features(p)[0, 0], expected)


def test_pruning_keeps_only_visited_cells():
    g = FieldGrid(3, 3, (0.0, 3.0, 0.0, 3.0))
    pts = np.array([[0.5, 0.5]] * 10 + [[2.5, 2.5]] * 3)
    b = RbfBasis.from_grid(g, pts, min_visits=5)
    np.testing.assert_allclose(b.centers, [[0.5, 0.5]])


def test_fitted_field_bounded_outside_training_region():
    truth = make_truth_model(3, seed=5, bounds=(-75, 75, -75, 75))
    run = simulate(truth, 6000, initial_positions(truth, seed=5, spread=25), seed=6)
    # deliberately a grid much larger than the visited region: unvisited cells are pruned
    fit = fit_herd([run], grid=(12, 12), bounds=(-300, 300, -300, 300))
    p = run.positions.reshape(-1, 2)
    lo, hi = p.min(0), p.max(0)
    for a in truth.agents:
        law = fit.model.laws[a]
        assert law.basis.size < 144
        inside = law.basis.features(run.positions[:, truth.agents.index(a)])
        g_in = np.hypot(inside @ law.field_u, inside @ law.field_v)
        xs = np.linspace(-1000, 1000, 81)
        gx, gy = np.meshgrid(xs, xs)
        far = np.column_stack([gx.ravel(), gy.ravel()])
        away = ((far < lo - 100) | (far > hi + 100)).any(1)
        phi = law.basis.features(far[away])
        g_out = np.hypot(phi @ law.field_u, phi @ law.field_v)
        assert g_out.max() <= g_in.max()
        assert g_out[np.abs(far[away]).max(1) >= 900].max() < 1e-6 * g_in.max()
