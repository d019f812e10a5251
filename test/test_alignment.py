"""Velocity alignment (issue 31): the columns by hand, the law, the fit and the selection
on known-truth herds, the model file, the RLS and the published parameters."""
import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.estimation.herd_fit import fit_structure
from herd_ros.estimation.model_selection import select_model
from herd_ros.estimation.online_fit import OnlineHerdEstimator
from herd_ros.herd_dynamics import HerdDynamics
from herd_ros.model import kinds
from herd_ros.model.alignment import AlignmentKernel, VelocityAlignment, alignment_columns
from herd_ros.model.distance_profile import DistanceProfile
from herd_ros.model.herd_model import AgentLaw, HerdModel
from herd_ros.model.model_structure import ModelStructure
from herd_ros.model.rbf_field import RbfBasis
from herd_ros.synthesis.known_truth import (ALIGNMENT_WEIGHTS, initial_positions,
                                            make_truth_model, with_alignment)

BOUNDS = (-75.0, 75.0, -75.0, 75.0)
PROFILE = DistanceProfile.even(40.0, 4)


def psi(d):
    """ψ_b(d) written out (Gaussian bumps at 5, 15, 25, 35 m, width 20/3, cosine taper)."""
    c = np.array([5.0, 15.0, 25.0, 35.0])
    return np.exp(-(d - c) ** 2 / (2 * (20 / 3) ** 2)) * 0.5 * (1 + np.cos(np.pi * d / 40))


def test_columns_by_hand_radius_and_nearest():
    # agent 0 at the origin; agent 1 10 m east, agent 2 30 m north, agent 3 beyond 40 m
    p = np.array([[[0.0, 0.0], [10.0, 0.0], [0.0, 30.0], [50.0, 0.0]]])
    u = np.array([[[1.0, 0.0], [0.0, 1.0], [-1.0, 2.0], [5.0, 5.0]]])
    cols = alignment_columns(p, u, [0], PROFILE)[0, 0]                 # (B, 2)
    want = (np.outer(psi(10.0), [-1.0, 1.0]) + np.outer(psi(30.0), [-2.0, 2.0])) / 2
    np.testing.assert_allclose(cols, want, atol=1e-15)
    near = alignment_columns(p, u, [0], PROFILE, 'nearest', nearest=1)[0, 0]
    np.testing.assert_allclose(near, np.outer(psi(10.0), [-1.0, 1.0]), atol=1e-15)
    # a neighbour without a velocity drops out (and out of the count)
    u2 = u.copy()
    u2[0, 2] = np.nan
    np.testing.assert_allclose(alignment_columns(p, u2, [0], PROFILE)[0, 0],
                               np.outer(psi(10.0), [-1.0, 1.0]), atol=1e-15)
    # an agent alone feels nothing
    assert not alignment_columns(p, u, [3], PROFILE).any()
    with pytest.raises(HerdInputError, match='neighbourhood'):
        alignment_columns(p, u, [0], PROFILE, 'topological')


def two_aligners(weight, damping=0.0):
    basis = RbfBasis(np.zeros((0, 2)), [])
    laws = {a: AgentLaw(damping, [b], [0.0], [0.0], basis, [], [], np.eye(2) * 1e-4)
            for a, b in (('a', 'b'), ('b', 'a'))}
    kernel = AlignmentKernel(PROFILE)
    return HerdModel(['a', 'b'], 1.0, laws, alignment=VelocityAlignment(
        kernel, np.full((2, 4), weight)))


def test_the_law_pulls_velocities_together():
    """Zero damping, alignment only: u_a^{τ+1} = K(d)(u_b − u_a) (one neighbour)."""
    model = two_aligners(0.5)
    p = np.array([[0.0, 0.0], [10.0, 0.0]])
    u = np.array([[1.0, 0.0], [0.0, 1.0]])
    k = 0.5 * psi(10.0).sum()
    np.testing.assert_allclose(model.next_velocity(u, p), [[-k, k], [k, -k]], atol=1e-15)
    # with damping 1 the difference δ = u_a − u_b obeys δ' = (1 − 2K(d)) δ: it vanishes
    # (0 < K < 1) and the mean velocity is kept (the pull is symmetric)
    traj = HerdDynamics(model=two_aligners(0.3, damping=1.0)).simulate(p, 30, u, noise=False)
    du = np.diff(traj.positions, axis=0)
    gap = np.linalg.norm(du[:, 0] - du[:, 1], axis=1)
    assert gap[-1] < 1e-6 * gap[0]
    np.testing.assert_allclose(du.mean(axis=1), np.tile([0.5, 0.5], (29, 1)), atol=1e-12)


@pytest.fixture(scope='module')
def aligned_herd():
    truth = with_alignment(make_truth_model(3, seed=4, grid=(4, 4), bounds=BOUNDS), seed=4)
    run = HerdDynamics(model=truth).simulate(initial_positions(truth, seed=4, spread=25),
                                             20000, seed=99)
    return truth, run


def test_fit_recovers_the_kernel_within_two_standard_errors(aligned_herd):
    truth, run = aligned_herd
    kernel = truth.alignment.kernel
    sel = select_model([run.positions], truth.agents, 1.0, grids=[(4, 4)], bounds=BOUNDS,
                       alignment=kernel, memories=())
    assert sel.chosen.alignment == kernel and sel.chosen.interactions
    fitted = fit_structure([run], sel.chosen, bounds=BOUNDS).model.alignment
    n = len(truth.agents)
    # the herd's kernel (mean weights over the animals) at every bump
    se = np.sqrt((fitted.se ** 2).sum(axis=0)) / n
    z = (fitted.coef.mean(axis=0) - truth.alignment.coef.mean(axis=0)) / se
    assert (np.abs(z) < 2).all(), z
    # each animal's weights: no bump beyond 3 standard errors (12 bumps in all)
    assert (np.abs((fitted.coef - truth.alignment.coef) / fitted.se) < 3).all()
    np.testing.assert_allclose(fitted.coef.mean(axis=0), np.mean(truth.alignment.coef, 0),
                               atol=3 * se.max())
    assert ALIGNMENT_WEIGHTS[0] > ALIGNMENT_WEIGHTS[-1]


@pytest.mark.parametrize('n_agents', [3, 5])
def test_selection_keeps_alignment_only_where_the_herd_has_it(n_agents):
    for aligned in (True, False):
        truth = make_truth_model(n_agents, seed=2, grid=(4, 4), bounds=BOUNDS)
        if aligned:
            truth = with_alignment(truth, seed=2)
        run = HerdDynamics(model=truth).simulate(
            initial_positions(truth, seed=2, spread=25), 8000, seed=7)
        sel = select_model([run.positions], truth.agents, 1.0, grids=[(4, 4)],
                           bounds=BOUNDS, memories=())          # alignment='auto'
        assert (sel.chosen.alignment is not None) == aligned, sel.chosen.label()
        assert sel.chosen.interactions and sel.chosen.grid == (4, 4)
        assert ('alignment' in sel.as_dict()['terms']) == aligned


def test_model_file_round_trip_and_a_malformed_entry(tmp_path, aligned_herd):
    truth, run = aligned_herd
    path = kinds.save(truth, tmp_path / 'm.yaml')
    back = kinds.load(path)
    np.testing.assert_allclose(back.alignment.coef, truth.alignment.coef)
    assert back.alignment.kernel == truth.alignment.kernel
    p = run.positions[:50]
    np.testing.assert_allclose(back.predict_one_step(p), truth.predict_one_step(p))
    text = path.read_text().replace('neighbourhood: radius', 'neighbourhood: ring')
    (tmp_path / 'bad.yaml').write_text(text)
    with pytest.raises(HerdInputError, match='neighbourhood'):
        kinds.load(tmp_path / 'bad.yaml')


def test_rls_learns_the_kernel_and_publishes_it(aligned_herd):
    truth, run = aligned_herd
    k = truth.alignment.kernel
    est = OnlineHerdEstimator(truth.agents, 1.0, field_grid=(4, 4), field_bounds=BOUNDS,
                              alignment=True, alignment_radius=k.profile.radius,
                              alignment_size=k.size)
    for t, p in zip(run.times, run.positions):
        est.add_snapshot(float(t), p)
    model = est.model()
    w, se = model.alignment.coef, model.alignment.se
    herd_se = np.sqrt((se ** 2).sum(axis=0)) / len(w)
    assert (np.abs(w.mean(0) - truth.alignment.coef.mean(0)) < 3 * herd_se).all()
    np.testing.assert_allclose(model.damping, truth.damping, rtol=0.02)
    # what a controller reads: θ with the structure message gives the estimator's law
    structure = ModelStructure.from_json(est.structure().to_json())
    assert structure.alignment_size == 4 and structure.n_params == est.theta.shape[1]
    law = HerdDynamics.from_parameters(est.theta, structure).model
    p0, p1 = run.positions[500], run.positions[501]
    H, _ = est.regressor.rows(p0, p1, 1.0)
    np.testing.assert_allclose(law.next_velocity(p1 - p0, p0),
                               np.einsum('nkp,np->nk', H, est.theta), atol=1e-12)
    # a structure message from before alignment (no alignment keys) still reads
    old = ModelStructure.from_json('{"agents": ["a", "b"], "dt": 1, "law": "pairwise", '
                                   '"field_grid": [1, 1], "field_bounds": [0, 1, 0, 1], '
                                   '"interaction_radius": 60, "profile_size": 6}')
    assert old.alignment_size == 0 and old.alignment_kernel() is None


def test_robots_align_with_each_other():
    """A robot on an aligning animal matches the other robots' velocity: one tick of the
    follower is u + K(d)(u_other − u) (damping 1), and a stale robot exerts nothing."""
    from herd_ros.control.herd_follower import follower_for
    follower = follower_for(two_aligners(0.3, damping=1.0), ['a', 'b'], ['r1', 'r2'])
    p = np.array([[0.0, 0.0], [10.0, 0.0]])
    u = np.array([[1.0, 0.0], [0.0, 1.0]])
    k = 0.3 * psi(10.0).sum()
    np.testing.assert_allclose(follower.advance(u, p, 1.0),
                               [[1 - k, k], [k, 1 - k]], atol=1e-12)
    np.testing.assert_allclose(follower.advance(u, p, 1.0, active=np.array([True, False])),
                               u, atol=1e-12)


def test_command_line_fits_reports_and_learns_alignment_online(tmp_path, capsys,
                                                               aligned_herd):
    from herd_ros.cli.main import main
    from herd_ros.trajectory import HerdTrajectory, write_trajectory_csv
    truth, run = aligned_herd
    data = tmp_path / 'aligned.csv'
    write_trajectory_csv(data, HerdTrajectory(run.times[:8000], run.agents,
                                              run.positions[:8000]))
    assert main(['fit', str(data), '-o', str(tmp_path / 'm.yaml'), '--grid', '4x4',
                 '--bounds=-75,75,-75,75', '--field', 'fitted', '--noise', 'gaussian',
                 '--report', str(tmp_path / 'rep')]) == 0
    out = capsys.readouterr().out
    assert 'alignment (4 bumps, neighbours within' in out
    assert 'damping+interactions+alignment+field' in out
    assert (tmp_path / 'rep' / 'fig2_alignment.png').stat().st_size > 0
    assert kinds.load(tmp_path / 'm.yaml').alignment is not None
    # the recursive fit with alignment on, from the command line's defaults otherwise
    assert main(['fit', str(data), '-o', str(tmp_path / 'online.yaml'), '--online',
                 '--alignment', 'on']) == 0
    online = kinds.load(tmp_path / 'online.yaml')
    assert online.alignment is not None and online.alignment.coef.shape == (3, 4)
    assert main(['fit', str(data), '-o', str(tmp_path / 'off.yaml'), '--grid', '4x4',
                 '--alignment', 'off', '--field', 'fitted', '--noise', 'gaussian']) == 0
    assert kinds.load(tmp_path / 'off.yaml').alignment is None


def test_one_step_and_large_herd_paths_equal_the_general_one():
    """The RLS's one-step path and the k-d tree path of large herds give the general
    (every pair, chunked) sums, both neighbourhoods, with missing agents."""
    import herd_ros.model.alignment as alignment
    rng = np.random.default_rng(3)
    for n in (12, 260):
        p = rng.uniform(-150, 150, size=(1, n, 2))
        u = rng.normal(size=(1, n, 2))
        p[0, 3] = np.nan
        u[0, 5] = np.nan
        two_p, two_u = np.concatenate([p, p]), np.concatenate([u, u])   # M = 2: general
        for hood in ('radius', 'nearest'):
            fast = alignment_columns(p, u, np.arange(n), PROFILE, hood, 4)[0]
            general = alignment_columns(two_p, two_u, np.arange(n), PROFILE, hood, 4)[1]
            np.testing.assert_allclose(fast, general, atol=1e-12)
    assert alignment.SPARSE_FROM_AGENTS < 260
