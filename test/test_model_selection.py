"""Model selection by blocked cross-validation (issue: predictions that beat naive baselines).

Independent expectations: the CV errors against brute-force refits on the other blocks;
the vectorised shared-law regressors against the per-snapshot ones of the online
estimator; the structure of known-truth herds; and, on the shipped real herds, held-out
one-step error against a damping-only model fitted independently on the same training data,
constant velocity and stay-put.
"""
import numpy as np
import pytest

from conftest import REPO
from herd_ros.data_sources import load_runs
from herd_ros.estimation.herd_fit import aligned_positions, fit_structure, split_runs
from herd_ros.estimation.model_selection import Structure, agent_samples, select_model
from herd_ros.model.model_file import load_model, save_model
from herd_ros.model.rbf_field import FieldGrid, RbfBasis
from herd_ros.model.shared_law import DistanceProfile, shared_columns, shared_rows
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.simulation.prediction import noise_level, predict_ahead, prediction_covariance
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model

BOUNDS = (-75.0, 75.0, -75.0, 75.0)


def known_herd(n, steps, seed=7):
    truth = make_truth_model(n, seed=seed, grid=(6, 6), bounds=BOUNDS)
    run = simulate(truth, steps, initial_positions(truth, seed=seed, spread=25), seed=seed + 1000)
    return truth, run


def test_shared_columns_equal_the_online_estimators_rows():
    rng = np.random.default_rng(0)
    profile = DistanceProfile.even(30.0, 4)
    pt = rng.uniform(-40, 40, size=(25, 7, 2))
    pt[3, 2] = np.nan                                   # a missing neighbour drops out
    for i in range(7):
        cols = shared_columns(pt, i, profile)[0][:, 0]
        for k in range(len(pt)):
            if not np.isfinite(pt[k, i]).all():
                continue
            H, _ = shared_rows(pt[k], pt[k], 1.0, profile, RbfBasis(np.zeros((0, 2)), []))
            np.testing.assert_allclose(cols[k, :, 0], H[i, 0, 1:5], atol=1e-12)
            np.testing.assert_allclose(cols[k, :, 1], H[i, 1, 1:5], atol=1e-12)


def test_cross_validation_errors_equal_brute_force_refits():
    """Every block predicted by a least-squares fit on the other blocks, done the long way
    (dense design, numpy lstsq / ridge normal equations) for two candidates."""
    truth, run = known_herd(3, 1200, seed=2)
    agents, dt = list(run.agents), run.dt
    folds = 4
    grid = (2, 2)
    sel = select_model([run.positions], agents, dt, folds=folds, grids=[grid],
                       ridges=(0.0, 0.01), bounds=BOUNDS, min_visits=1)
    edges = np.linspace(0, run.n_steps - 2, folds + 1).astype(int)
    basis_grid = FieldGrid(grid[0], grid[1], BOUNDS)
    for structure in (Structure(True, grid, 0.0), Structure(True, None, 0.01),
                      Structure(False, grid, 0.01), Structure(False, None, 0.0)):
        sse = n = 0.0
        for i in range(len(agents)):
            visited = run.positions[:-2, i]
            basis = RbfBasis.from_grid(basis_grid, visited, 1)

            def design(p):
                A_x, A_y, y_x, y_y, pts = agent_samples(p, i, dt, 'pairwise', None)
                if not structure.interactions:
                    A_x, A_y = A_x[:, :1], A_y[:, :1]
                F = basis.features(pts) if structure.grid else np.zeros((len(pts), 0))
                Z = np.zeros_like(F)
                return (np.vstack([np.hstack([A_x, F, Z]), np.hstack([A_y, Z, F])]),
                        np.concatenate([y_x, y_y]))

            blocks = [design(run.positions[b0:b1 + 2]) for b0, b1 in zip(edges[:-1], edges[1:])]
            for b in range(folds):
                X = np.vstack([blocks[k][0] for k in range(folds) if k != b])
                y = np.concatenate([blocks[k][1] for k in range(folds) if k != b])
                if structure.ridge:
                    D2 = np.diag((X ** 2).sum(0))
                    D2[0, 0] = 0.0           # the damping (first column) is not penalised
                    theta = np.linalg.solve(X.T @ X + structure.ridge * D2, X.T @ y)
                else:
                    theta = np.linalg.lstsq(X, y, rcond=None)[0]
                Xb, yb = blocks[b]
                sse += ((Xb @ theta - yb) ** 2).sum()
                n += len(yb) / 2
        expected = dt * np.sqrt(sse / n)
        got = next(r['rms'] for r in sel.table if r['structure'] == structure)
        assert got == pytest.approx(expected, rel=1e-7), structure


@pytest.mark.parametrize('n_agents', [3, 10])
def test_known_truth_herds_select_interactions_and_field(n_agents):
    """The truth has a field and interactions (pairwise; with 10 agents the selection's
    interaction term is the shared law): both must be selected."""
    truth, run = known_herd(n_agents, 20000)
    sel = select_model([run.positions], list(run.agents), run.dt)
    assert sel.chosen.interactions and sel.chosen.grid is not None, sel.chosen
    # no agent of the truth is distinguished: none gets its own profile
    assert not sel.chosen.own, sel.chosen
    # and it predicts better than the baselines in cross-validation
    best = next(r['rms'] for r in sel.table if r['structure'] == sel.chosen)
    assert best < sel.baselines['constant_velocity'] < sel.baselines['stay_put']


def test_a_selected_model_without_field_or_interactions_round_trips(tmp_path):
    truth, run = known_herd(3, 3000)
    fit = fit_structure([run], Structure(False, None, 0.0), bounds=BOUNDS)
    model = fit.model
    assert not np.any(model.theta1) and not np.any(model.theta2)
    # damping-only: a = Σ u·u' / Σ |u|² per agent, computed here by hand
    u = np.diff(run.positions, axis=0)
    a = (u[:-1] * u[1:]).sum((0, 2)) / (u[:-1] ** 2).sum((0, 2))
    np.testing.assert_allclose(model.damping, a, rtol=1e-9)
    save_model(model, tmp_path / 'm.yaml')
    again = load_model(tmp_path / 'm.yaml')
    np.testing.assert_allclose(again.drift(run.positions[:5]), 0.0, atol=1e-15)


@pytest.fixture(scope='module', params=['baboons_1h', 'steers_72h.csv'])
def real_fit(request):
    """A shipped real herd: the first 80 % trains the selected fit (as `herd-ros fit` does
    by default), the last 20 % is held out."""
    runs, _ = load_runs(REPO / 'bags' / request.param)
    train, test = split_runs(runs, 0.8)
    agents = list(runs[0].agents)
    sel = select_model([aligned_positions(r, agents) for r in train], agents, train[0].dt)
    model = fit_structure(train, sel.chosen, law=sel.law, profile=sel.profile,
                          bounds=sel.bounds).model
    return request.param, runs, train, test, sel, model


@pytest.mark.slow
def test_on_real_herds_the_selected_fit_is_never_worse_than_damping_only(real_fit):
    """Held-out one-step RMS against a damping-only model fitted here, independently, on the
    same training data (one least-squares a per agent), constant velocity and stay-put."""
    name, runs, train, test, sel, model = real_fit
    agents = model.agents
    num = den = 0.0
    for r in train:
        u = np.diff(aligned_positions(r, agents), axis=0)
        ok = np.isfinite(u[:-1]).all(-1) & np.isfinite(u[1:]).all(-1)
        num = num + np.where(ok, (u[:-1] * u[1:]).sum(-1), 0).sum(0)
        den = den + np.where(ok, (u[:-1] ** 2).sum(-1), 0).sum(0)
    a = num / den
    sq = {m: [] for m in ('selected', 'damping_only', 'constant_velocity', 'stay_put')}
    for r in test:
        p = aligned_positions(r, agents)
        truth = p[2:]
        for m, pred in (('selected', model.predict_one_step(p)),
                        ('damping_only', p[1:-1] + a[None, :, None] * (p[1:-1] - p[:-2])),
                        ('constant_velocity', 2 * p[1:-1] - p[:-2]),
                        ('stay_put', p[1:-1])):
            sq[m].append(((pred - truth) ** 2).sum(-1).ravel())
    rms = {m: float(np.sqrt(np.nanmean(np.concatenate(v)))) for m, v in sq.items()}
    print(name, sel.chosen.label(), {m: round(v, 4) for m, v in rms.items()})
    assert rms['selected'] <= rms['damping_only'] * (1 + 1e-6), rms
    # issue acceptance: at least 5 % better than the better naive baseline (measured:
    # baboons 15 %, steers 7.5 % with the velocity memory the selection keeps for them)
    assert rms['selected'] <= 0.95 * min(rms['constant_velocity'], rms['stay_put']), rms


@pytest.mark.slow
def test_on_real_herds_90_percent_ellipses_hold_85_to_95_percent(real_fit):
    """Issue acceptance 2: one-step 90 % prediction ellipses over the held-out part (the
    predictions made from the whole recording, as `herd-ros predict` does)."""
    name, runs, train, test, sel, model = real_fit
    r = runs[0]
    p = aligned_positions(r, model.agents)
    pred = predict_ahead(model, p, 1)
    cov = prediction_covariance(model, 1)[None] * noise_level(model, p, 1)[..., None, None]
    held = r.times >= test[0].times[0]
    ok = np.isfinite(pred).all(-1) & np.isfinite(p).all(-1) & held[:, None]
    e = (p - pred)[ok]
    m2 = np.einsum('mi,mij,mj->m', e, np.linalg.inv(cov[ok]), e)
    coverage = float(np.mean(m2 <= 4.605170185988091))
    print(name, 'held-out coverage of the 90 % ellipses', round(coverage, 4), len(m2))
    assert 0.85 <= coverage <= 0.95, coverage


def test_k_step_damping_only_closed_form_equals_iterating_the_law():
    """p̂^{s+k} = p^s + (a + … + a^k)(p^s − p^{s−1}) (closed form in k_step_rms) against the
    damping-only model iterated step by step, on the same starts."""
    from herd_ros.simulation.prediction import k_step_rms
    truth, run = known_herd(3, 3000)
    model = fit_structure([run], Structure(False, None, 0.0), bounds=BOUNDS).model
    out = k_step_rms(model, [run], ks=(1, 5, 30), damping=model.damping)
    for k in ('1', '5', '30'):
        k = int(k)
        assert out['damping_only'][k] == pytest.approx(out['model'][k], rel=1e-9)
    assert out['stay_put'][30] > out['model'][1]


@pytest.mark.slow
def test_on_real_herds_the_long_run_terms_make_the_simulated_herd_move_like_the_animals(real_fit):
    """Issue 10 acceptance 3 offline: the selected law with the space-use field and the
    noise regimes (`herd-ros fit --field space-use --noise regimes`; both from the training
    80 % only) simulated freely over the whole recording from its first complete step; herd
    means of mean and std of the distance to the others and of the speed within 30 % of the
    animals' (measured: steers +22 / −1 / +17 / −8 %, baboons +2 / −4 / +13 / −9 %; without
    them the steers' robots spread 10× too far and move 84 % too fast)."""
    from herd_ros.model.noise_regimes import with_noise_regimes
    from herd_ros.model.space_use_field import with_space_use_field
    from herd_ros.simulation.statistics import STATISTICS, herd_statistics
    name, runs, train, test, sel, model = real_fit
    positions = [aligned_positions(r, model.agents) for r in train]
    law = with_space_use_field(model, np.concatenate(positions))
    law, regimes = with_noise_regimes(law, positions)
    assert regimes['n_regimes'] > 1, regimes['bic']      # both herds rest and move
    p = aligned_positions(runs[0], model.agents)
    complete = np.isfinite(p).all(-1).all(-1)
    k0 = int(np.argmax(complete[:-1] & complete[1:]))
    sim = simulate(law, len(p) - k0, p[k0], (p[k0 + 1] - p[k0]) / model.dt, seed=0)
    real, robots = herd_statistics(runs[0]), herd_statistics(sim)
    for k in STATISTICS:
        want = np.nanmean([real[a][k] for a in model.agents])
        got = np.nanmean([robots[a][k] for a in model.agents])
        print(name, k, round(got, 4), 'vs', round(want, 4), f'{100 * (got / want - 1):+.0f} %')
        assert abs(got / want - 1) < 0.30, (name, k, got, want)


def test_held_out_samples_outside_the_training_region_are_not_scored():
    """Issue 26: a held-out block that leaves the region the other blocks cover would judge
    every candidate on extrapolation. Agent 0 spends its last block in a far corner no
    other block visits: exactly those samples go unscored; everything else is scored."""
    from herd_ros.estimation.model_selection import select_model
    rng = np.random.default_rng(3)
    T, folds = 1002, 10
    p = np.empty((T, 2, 2))
    p[:, 0] = 2.0 + 0.5 * rng.random((T, 2))        # both in one 12.5 m cell ...
    p[:, 1] = 2.0 + 0.5 * rng.random((T, 2))
    edges = np.linspace(0, T - 2, folds + 1).astype(int)
    p[edges[-2]:, 0] += 90.0                         # ... but agent 0's last block
    sel = select_model([p], ['a', 'b'], 1.0, grids=[(8, 8)], folds=folds,
                       bounds=(0.0, 100.0, 0.0, 100.0), memories=())
    assert sel.outside_region == edges[-1] - edges[-2]
    assert sel.samples == 2 * (T - 2) - sel.outside_region
    assert sel.as_dict()['held_out_samples']['outside_training_region'] == sel.outside_region


def test_the_one_standard_error_rule_refuses_a_simpler_candidate_that_is_erratic_and_worse():
    """Hand-made block errors (10 blocks of 100 samples): the best (3 parameters) is 1.0 in
    eight blocks, 0.95 and 1.05 in the last two (its standard error over the blocks
    0.00745); "steady" (2 parameters) is 0.025 above or 0.015 below it by turns (mean
    excess 0.005, paired standard error 0.0063); "erratic" (1 parameter) is 1.0 in eight
    blocks, 0.2 and 40 in the last two (mean 4.72, excess 3.82). Paired over the blocks,
    erratic's excess is within its own standard error (3.90: its one bad block makes it
    large), so the paired rule alone would take it; the best's own standard error refuses
    it, and steady, within both, is chosen."""
    from herd_ros.estimation.model_selection import _one_standard_error
    count = np.full(10, 100.0)
    best_blocks = np.array([1.0] * 8 + [0.95, 1.05])
    mse = {'best': best_blocks, 'steady': best_blocks + np.tile([0.025, -0.015], 5),
           'erratic': np.array([1.0] * 8 + [0.2, 40.0])}
    sse = {k: v * count for k, v in mse.items()}
    n_params = {'best': 3, 'steady': 2, 'erratic': 1}
    table, chosen = _one_standard_error(list(mse), sse, n_params, count, 1.0)
    rows = {r['structure']: r for r in table}
    assert rows['erratic']['excess'] == pytest.approx(3.82, abs=1e-9)
    assert rows['erratic']['excess'] <= rows['erratic']['excess_se']   # paired: eligible
    assert rows['steady']['excess'] == pytest.approx(0.005, abs=1e-9)
    assert rows['steady']['excess'] <= rows['steady']['excess_se']
    assert chosen == 'steady'
    # with steady left out, the best itself (never the erratic one)
    _, chosen = _one_standard_error(['best', 'erratic'], sse, n_params, count, 1.0)
    assert chosen == 'best'
