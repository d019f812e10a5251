"""Each collar's motion model fitted by maximum likelihood (:mod:`herd_ros.ingest.motion_fit`).

Known-truth checks: tracks simulated exactly from an integrated Ornstein-Uhlenbeck velocity
(or a random walk) with known parameters, seen at irregular 30-300 s fixes with known
noise; the fit recovers the parameters and AIC picks the model that made the data. The
exact discretisation is checked against Van Loan's matrix exponential (an independent
computation of the same integral).
"""
import math

import numpy as np
import pytest
from scipy.linalg import expm

from herd_ros.ingest.motion_fit import MotionFit, fit_motion, iou_discretisation


def simulate_iou(rng, n, velocity_tau, diffusion, position_std, lo=30.0, hi=300.0):
    """Exact samples of the 2-D IOU (per axis: dv = −v/τ dt + σ dW, dp = v dt) at
    irregular times, plus white measurement noise."""
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(lo, hi, n - 1))])
    accel = math.sqrt(diffusion) / velocity_tau
    x = np.zeros((2, 2))                      # rows: p, v; columns: axes
    x[1] = rng.normal(0.0, math.sqrt(diffusion / (2 * velocity_tau)), 2)
    out = [x[0].copy()]
    for dt in np.diff(t):
        f, g, qpp, qpv, qvv = iou_discretisation(dt, velocity_tau, accel)
        Q = np.array([[qpp, qpv], [qpv, qvv]])
        L = np.linalg.cholesky(Q + 1e-15 * np.eye(2))
        x = np.array([[1.0, f], [0.0, g]]) @ x + L @ rng.normal(size=(2, 2))
        out.append(x[0].copy())
    z = np.asarray(out) + rng.normal(0.0, position_std, (n, 2))
    return t, z


@pytest.mark.parametrize('tau,beta', [(1.0, 0.5), (60.0, 1 / 60.0), (3000.0, 1 / 3000.0)])
def test_the_discretisation_is_the_exact_integral(tau, beta):
    """Van Loan (1978): expm([[−A, GGᵀ], [0, Aᵀ]] τ) holds F and Q = F · (upper right)."""
    sigma = 0.3
    A = np.array([[0.0, 1.0], [0.0, -beta]])
    G = np.array([[0.0], [sigma]])
    M = np.zeros((4, 4))
    M[:2, :2] = -A
    M[:2, 2:] = G @ G.T
    M[2:, 2:] = A.T
    E = expm(M * tau)
    F = E[2:, 2:].T
    Q = F @ E[:2, 2:]
    f, g, qpp, qpv, qvv = iou_discretisation(tau, 1.0 / beta, sigma)
    np.testing.assert_allclose([[1.0, f], [0.0, g]], F, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose([[qpp, qpv], [qpv, qvv]], Q, rtol=1e-6, atol=1e-12)


def test_a_correlated_walk_is_recovered_and_chosen_over_a_random_walk():
    rng = np.random.default_rng(7)
    truth = dict(velocity_tau=600.0, diffusion=0.5, position_std=3.0)
    tracks = [simulate_iou(rng, 400, **truth) for _ in range(3)]
    fits = fit_motion([(t, z, np.full(len(t), np.nan)) for t, z in tracks], max_fixes=400)
    for f in fits:
        assert f.model == 'iou'
        assert 0.5 < f.velocity_tau / truth['velocity_tau'] < 2.0, f
        assert 0.5 < f.diffusion / truth['diffusion'] < 2.0, f
        assert 0.7 < f.position_std / truth['position_std'] < 1.4, f


def test_a_random_walk_is_chosen_for_a_random_walk_and_its_diffusion_recovered():
    rng = np.random.default_rng(8)
    # velocity forgets itself in 2 s, fixes every 30-300 s: a random walk at these scales
    tracks = [simulate_iou(rng, 400, velocity_tau=2.0, diffusion=0.2, position_std=2.0)
              for _ in range(3)]
    fits = fit_motion([(t, z, np.full(len(t), np.nan)) for t, z in tracks], max_fixes=400)
    # AIC keeps the needless τ_v of an IOU now and then (ℓ is flat in τ_v ≪ the
    # intervals): most collars are random walks, and every fit forgets its velocity
    # well within an interval
    assert sum(f.model == 'rw' for f in fits) >= 2, fits
    for f in fits:
        assert f.velocity_tau < 30.0, f
        assert 0.6 < f.diffusion / 0.2 < 1.6, f
        assert 0.6 < f.position_std / 2.0 < 1.5, f


def test_given_covariances_are_used_and_not_fitted():
    rng = np.random.default_rng(9)
    t, z = simulate_iou(rng, 300, velocity_tau=2.0, diffusion=0.2, position_std=2.0)
    (f,) = fit_motion([(t, z, np.full(len(t), 4.0))])
    assert math.isnan(f.position_std)
    assert 0.6 < f.diffusion / 0.2 < 1.6, f


def test_a_collar_with_few_fixes_takes_the_pooled_prior():
    rng = np.random.default_rng(10)
    many = [simulate_iou(rng, 200, velocity_tau=2.0, diffusion=0.2, position_std=2.0)
            for _ in range(2)]
    few = simulate_iou(rng, 8, velocity_tau=2.0, diffusion=0.2, position_std=2.0)
    tracks = [(t, z, np.full(len(t), np.nan)) for t, z in many + [few]]
    fits = fit_motion(tracks)
    assert fits[2].model == 'prior' and fits[2].n_fixes == 0
    assert 0.5 < fits[2].diffusion / 0.2 < 2.0
    # with no collar rich enough, every collar gets the caller's default
    default = MotionFit('prior', 1.0, 0.05, 5.0, math.nan, math.nan, 0)
    assert fit_motion([tracks[2]], default=default) == [default]


def test_bad_fixes_are_left_out_not_fatal():
    rng = np.random.default_rng(11)
    t, z = simulate_iou(rng, 100, velocity_tau=2.0, diffusion=0.2, position_std=2.0)
    z[5] = np.nan
    t = np.concatenate([t[:10], t[9:10], t[10:]])      # a duplicated stamp
    z = np.concatenate([z[:10], z[9:10], z[10:]])
    (f,) = fit_motion([(t, z, np.full(len(t), np.nan))])
    assert f.n_fixes == 99 and np.isfinite(f.loglik)


def test_the_compiled_likelihood_is_the_vectorised_one():
    from herd_ros.ingest import collar_bank
    from herd_ros.ingest.motion_fit import (_pack, innovation_loglik,
                                            innovation_loglik_numpy, one_step_distances)
    if not collar_bank.AVAILABLE:
        pytest.skip('no compiled kernels')
    rng = np.random.default_rng(12)
    tracks = [simulate_iou(rng, k, velocity_tau=60.0, diffusion=0.3, position_std=2.0)
              for k in (50, 80)]
    r = [np.where(rng.random(len(t)) < 0.5, np.nan, 5.0) for t, _ in tracks]
    t, z, rr, n = _pack([(t, zz, ri) for (t, zz), ri in zip(tracks, r)], 100)
    tv = np.array([[5.0, 60.0, 900.0]] * 2)
    D = np.array([[0.1, 0.3, 1.0]] * 2)
    sm = np.array([[1.0, 4.0, 9.0]] * 2)
    for walk in (None, (0.05, 120.0, 0.05)):
        np.testing.assert_allclose(innovation_loglik(t, z, rr, n, tv, D, sm, walk),
                                   innovation_loglik_numpy(t, z, rr, n, tv, D, sm, walk),
                                   rtol=1e-10)
        np.testing.assert_allclose(one_step_distances(t, z, rr, n, tv, D, sm, walk),
                                   innovation_loglik_numpy(t, z, rr, n, tv, D, sm, walk,
                                                           distance=True), rtol=1e-10)


@pytest.mark.parametrize('compiled', [True, False])
def test_the_one_step_distance_of_a_follower_is_the_fix_to_fix_distance(compiled, kernels):
    """Fixes trusted to 0.1 mm under a random walk whose velocity forgets itself in 10 ms:
    the filter is at each fix, and predicts the next where the last was. The mean
    distance is the mean of ‖z_k − z_{k−1}‖, by hand."""
    from herd_ros.ingest.motion_fit import (_pack, innovation_loglik_numpy,
                                            one_step_distance)
    rng = np.random.default_rng(21)
    t = np.cumsum(rng.uniform(30.0, 300.0, 40))
    z = np.cumsum(rng.normal(0.0, 10.0, (40, 2)), axis=0)
    tp, zp, rp, n = _pack([(t, z, np.full(40, np.nan))], 50)
    args = (tp, zp, rp, n, np.array([[0.01]]), np.array([[1.0]]), np.array([[1e-8]]))
    d = one_step_distance(*args) if compiled else np.nanmean(
        innovation_loglik_numpy(*args, distance=True), axis=-1)
    assert d[0, 0] == pytest.approx(np.mean(np.hypot(*np.diff(z, axis=0).T)), rel=1e-4)


def test_the_one_step_distance_of_a_constant_velocity_track(kernels):
    """A collar on a straight line at 0.5 m/s, a fix a minute, trusted to 0.1 mm, under an
    IOU whose velocity persists (τ_v 10⁶ s): the first prediction is the first fix (its
    velocity taken as 0), every later one exact. Mean distance: 30 m over the 19
    predictions, by hand, from the compiled loop and the numpy reference."""
    from herd_ros.ingest.motion_fit import (_pack, innovation_loglik_numpy,
                                            one_step_distance)
    t = 60.0 * np.arange(20)
    z = np.outer(0.5 * t, [0.6, 0.8])
    tp, zp, rp, n = _pack([(t, z, np.full(20, np.nan))], 20)
    args = (tp, zp, rp, n, np.array([[1e6]]), np.array([[1e4]]), np.array([[1e-8]]))
    expected = 30.0 / 19
    assert one_step_distance(*args)[0, 0] == pytest.approx(expected, rel=1e-3)
    steps = innovation_loglik_numpy(*args, distance=True)[0, 0]
    assert np.isnan(steps[0]) and np.isfinite(steps[1:]).all()
    assert np.mean(steps[1:]) == pytest.approx(expected, rel=1e-3)


def test_the_closer_predictor_beyond_chance_by_hand():
    """The Diebold-Mariano test of :func:`significantly_closer`, by hand: differences
    d_new − d_old of mean −1 and std 2 over 16 fixes give t = −1 / (2 / 4) = −2 (closer
    beyond chance at z 1.645, not at 2.5); over 4 fixes t = −1 (not); a predictor that is
    farther, or the same, never is; a fixed improvement (std 0) is."""
    from herd_ros.ingest.motion_fit import significantly_closer
    base = np.array([1.0, -1.0] * 8)                  # mean 0, sample std 16/15 ** 0.5
    diff16 = -1.0 + base * 2.0 / np.sqrt(16.0 / 15.0)  # mean −1, sample std 2
    old = np.full((1, 16), 10.0)
    assert np.std(diff16, ddof=1) == pytest.approx(2.0)
    assert significantly_closer(old + diff16, old).tolist() == [True]
    assert significantly_closer(old + diff16, old, z=2.5).tolist() == [False]
    diff4 = -1.0 + np.array([1.0, -1.0, 1.0, -1.0]) * 2.0 / np.sqrt(4.0 / 3.0)
    assert significantly_closer(old[:, :4] + diff4, old[:, :4]).tolist() == [False]
    assert significantly_closer(old - diff16, old).tolist() == [False]
    assert significantly_closer(old, old).tolist() == [False]
    assert significantly_closer(old - 0.5, old).tolist() == [True]
    nan = np.full((1, 16), np.nan)                     # no pairs: never
    assert significantly_closer(nan, old).tolist() == [False]


def test_a_correlated_walk_is_kept_only_where_it_also_predicts_better(kernels):
    """The IOU is chosen where it is both the likelier model (AIC) and the closer one-step
    predictor on the window beyond chance: on known-truth correlated walks (τ_v 600 s) it
    is, and its mean one-step distance is below the random walk's; collars whose velocity
    forgets itself within the intervals (τ_v 0.5 s) are random walks."""
    from herd_ros.ingest.motion_fit import _pack, one_step_distance
    rng = np.random.default_rng(7)
    tracks = [simulate_iou(rng, 300, velocity_tau=600.0, diffusion=0.5, position_std=3.0)
              for _ in range(2)]
    tracks += [simulate_iou(rng, 300, velocity_tau=0.5, diffusion=0.5, position_std=3.0)
               for _ in range(2)]
    cols = [(t, z, np.full(len(t), np.nan)) for t, z in tracks]
    fits = fit_motion(cols, max_fixes=300)
    assert [f.model for f in fits] == ['iou', 'iou', 'rw', 'rw']
    t, z, r, n = _pack(cols, 300)
    for j, f in enumerate(fits[:2]):
        pts = np.array(f.optima)              # (random walk, IOU): log10 (τ_v, σ_a, σ_m²)
        tv = 10.0 ** pts[:, 0]
        d = one_step_distance(t[j:j + 1], z[j:j + 1], r[j:j + 1], n[j:j + 1], tv[None],
                              ((10.0 ** pts[:, 1] * tv) ** 2)[None],
                              (10.0 ** pts[:, 2])[None])[0]
        assert d[1] < d[0]


def _bounded_velocity_collars(n_collars, seed):
    """Collars seen every 1-1.2 s with 3 m noise, their velocity a bounded random walk
    (the ingest benchmark's herd)."""
    rng = np.random.default_rng(seed)
    tracks = []
    for _ in range(n_collars):
        t = np.cumsum(rng.uniform(1.0, 1.2, 200))
        v = np.cumsum(rng.normal(0.0, 0.02, (200, 2)), axis=0).clip(-1.0, 1.0)
        z = np.cumsum(v, axis=0) + rng.normal(0.0, 3.0, (200, 2))
        tracks.append((t, z, np.full(200, np.nan)))
    return tracks


WALK = (1.0, 60.0, 0.05, 25.0)


def test_the_fit_finds_the_best_of_a_dense_grid():
    """Each model's optimum (``optima``) is at least as likely as the best point of a dense
    grid over the whole search box (an exhaustive search, independent of the optimiser's
    starts); the IOU's likelihood has more than one basin on these collars."""
    from herd_ros.ingest.motion_fit import TAU_MAX, _pack, innovation_loglik
    tracks = _bounded_velocity_collars(6, seed=2)
    fits = fit_motion(tracks, walk=WALK)
    t, z, r, n = _pack(tracks, 200)
    tv_rw = 0.1 * np.percentile(np.diff(t, axis=1), 10, axis=1)
    for model in (0, 1):
        x = np.array([f.optima[model] for f in fits])             # log10 τ, σ_a, σ_m²
        tv = 10.0 ** x[:, :1]
        at_fit = innovation_loglik(t, z, r, n, tv, (10.0 ** x[:, 1:2] * tv) ** 2,
                                   10.0 ** x[:, 2:3], WALK)[:, 0]
        if model == 0:
            lt = np.log10(tv_rw)[:, None, None, None] * np.ones((1, 1, 40, 16))
        else:
            lt = np.linspace(np.log10(3.0 * tv_rw), np.full(6, np.log10(TAU_MAX)), 30).T
            lt = lt[:, :, None, None] * np.ones((1, 1, 40, 16))
        la = np.linspace(-6.0, 1.0, 40)[None, None, :, None] + 0.0 * lt
        ls = np.linspace(np.log10(0.25), 2.5, 16)[None, None, None, :] + 0.0 * lt
        lt, la, ls = (q.reshape(6, -1) for q in (lt, la, ls))
        tvg = 10.0 ** lt
        grid = innovation_loglik(t, z, r, n, tvg, (10.0 ** la * tvg) ** 2, 10.0 ** ls, WALK)
        assert (at_fit >= grid.max(axis=1) - 0.1).all(), (model, at_fit, grid.max(axis=1))


def test_a_refit_on_the_same_fixes_is_no_worse_than_the_first_fit():
    """Maximum likelihood on the same data started from its own optimum: the chosen
    model's AIC is no worse (to the search's tolerance), nor a kept model's ℓ."""
    tracks = _bounded_velocity_collars(40, seed=1)
    first = fit_motion(tracks, walk=WALK)
    again = fit_motion(tracks, walk=WALK, start=first)
    for f, g in zip(first, again):
        assert g.aic <= f.aic + 0.5, (f, g)
        if g.model == f.model:
            assert g.loglik >= f.loglik - 0.5, (f, g)


def test_the_start_values_of_all_collars_at_once_are_each_collars_own():
    """The vectorised starts (interval percentiles, the variogram's least squares) of
    padded collars of different lengths equal numpy's per-collar percentile and lstsq."""
    from herd_ros.ingest.motion_fit import interval_percentile, moment_start
    rng = np.random.default_rng(7)
    N, K = 12, 40
    t = np.cumsum(rng.uniform(1.0, 300.0, (N, K)), axis=1)
    z = np.cumsum(rng.normal(0.0, 5.0, (N, K, 2)), axis=1)
    n = rng.integers(3, K + 1, N)
    for j in range(N):
        t[j, n[j]:] = t[j, n[j] - 1]
        z[j, n[j]:] = 1e6                     # padding never enters
    D, s2 = moment_start(t, z, None, n, 0.25)
    for q in (10.0, 50.0):
        got = interval_percentile(t, n, q)
        want = [np.percentile(np.diff(t[j, :n[j]]), q) for j in range(N)]
        assert np.allclose(got, want, rtol=1e-12)
    for j in range(N):
        dt = np.diff(t[j, :n[j]])
        y = 0.25 * (np.diff(z[j, :n[j]], axis=0) ** 2).sum(axis=1)
        coef = np.linalg.lstsq(np.column_stack([dt, np.full(len(dt), 2.0)]), y, rcond=None)[0]
        assert D[j] == pytest.approx(np.clip(coef[0], 1e-5, 1e3), rel=1e-9)
        assert s2[j] == pytest.approx(np.clip(coef[1], 0.25, 1e4), rel=1e-9)


def test_each_collars_search_is_its_own_alone_or_beside_others():
    """The compiled Nelder-Mead searches two collars side by side (its lanes): a collar's
    optimum is the same, to the last bit, alone as in any batch (windows of different
    lengths, held coordinates, a collar with nothing free, with and without the walk
    component), and the ℓ it reports is the likelihood at the point it reports."""
    from herd_ros.ingest import collar_bank
    from herd_ros.ingest.motion_fit import HUBER_NIS, NM_FTOL, _pack, innovation_loglik
    if not collar_bank.AVAILABLE:
        pytest.skip('no compiled kernels')
    K = collar_bank.KERNELS
    rng = np.random.default_rng(5)
    lengths = (60, 60, 45, 3, 60, 2, 30, 59, 1)
    tracks = []
    for k in lengths:
        t, z = simulate_iou(rng, k, velocity_tau=rng.uniform(30, 3000),
                            diffusion=rng.uniform(0.01, 1.0), position_std=3.0)
        z[rng.random(k) < 0.1] += 200.0                      # a few bursts
        tracks.append((t, z, np.where(rng.random(k) < 0.5, np.nan, 9.0)))
    t, z, r, n = _pack(tracks, 60)
    N = len(n)
    x0 = np.column_stack([rng.uniform(1.5, 3.0, N), rng.uniform(-3.0, -1.0, N),
                          rng.uniform(0.0, 1.5, N)])
    lo = np.tile([0.5, -8.0, -0.6], (N, 1))
    hi = np.tile([5.2, 2.0, 4.0], (N, 1))
    step = np.tile([0.5, 0.5, 0.5], (N, 1))
    step[1, 0] = step[4, 2] = 0.0                            # held coordinates
    step[6] = 0.0                                           # nothing free
    evals = rng.integers(10, 90, N).astype(np.int64)
    for walk in ((0.0, 1.0, 0.5, 0.0), (0.1, 0.5, 0.05, 0.3)):
        def search(rows):
            x, ll = np.empty((len(rows), 3)), np.empty(len(rows))
            c = np.ascontiguousarray
            K.motion_nelder_mead(c(t[rows]), c(z[rows]), c(r[rows]), c(n[rows]), c(x0[rows]),
                                 c(lo[rows]), c(hi[rows]), c(step[rows]), *walk, HUBER_NIS,
                                 c(evals[rows]), NM_FTOL, x, ll)
            return x, ll
        x_all, ll_all = search(np.arange(N))
        for i in range(N):
            x_one, ll_one = search(np.array([i]))
            assert np.array_equal(x_one[0], x_all[i]) and ll_one[0] == ll_all[i]
        x_rev, ll_rev = search(np.arange(N)[::-1])
        assert np.array_equal(x_rev[::-1], x_all) and np.array_equal(ll_rev[::-1], ll_all)
        assert np.all((x_all >= lo) & (x_all <= hi))
        tv = 10.0 ** x_all[:, :1]
        D = (10.0 ** x_all[:, 1:2] * tv) ** 2
        w = None if walk[0] <= 0 else walk
        want = innovation_loglik(t, z, r, n, tv, D, 10.0 ** x_all[:, 2:], w)[:, 0]
        np.testing.assert_allclose(ll_all, want, rtol=1e-12, atol=1e-9)


def test_a_grid_of_points_gives_what_each_point_alone_gives():
    """The compiled likelihood evaluates a collar's grid points two at a time: the same
    numbers, to the last bit, as each point on its own (an odd and an even grid)."""
    from herd_ros.ingest import collar_bank
    from herd_ros.ingest.motion_fit import _pack, innovation_loglik
    if not collar_bank.AVAILABLE:
        pytest.skip('no compiled kernels')
    rng = np.random.default_rng(8)
    tracks = [simulate_iou(rng, k, velocity_tau=300.0, diffusion=0.2, position_std=2.0)
              for k in (40, 25, 2)]
    t, z, r, n = _pack([(ti, zi, np.full(len(ti), np.nan)) for ti, zi in tracks], 40)
    for G in (5, 6):
        tv = 10 ** rng.uniform(0, 3, (3, G))
        D = 10 ** rng.uniform(-3, 0, (3, G))
        sm = 10 ** rng.uniform(0, 1.5, (3, G))
        for walk in (None, (0.1, 120.0, 0.05, 25.0)):
            grid = innovation_loglik(t, z, r, n, tv, D, sm, walk)
            alone = np.column_stack([innovation_loglik(t, z, r, n, tv[:, g:g + 1],
                                                       D[:, g:g + 1], sm[:, g:g + 1], walk)
                                     for g in range(G)])
            assert np.array_equal(grid, alone)


def test_speed_std_is_the_stationary_one_and_undefined_at_the_constant_velocity_end():
    """√(D / 2τ_v) by hand; a fit at the constant-velocity end (τ_v at TAU_MAX) has none:
    the table shows ``cv end`` rather than tens of m/s."""
    from herd_ros.ingest.motion_fit import TAU_MAX
    from herd_ros.ingest.pipeline import format_motion_fits
    walk = MotionFit('iou', 10.0, 0.5, 1.0, -1.0, 2.0, 50)
    assert walk.speed_std == pytest.approx(math.sqrt(0.5 / 20.0), rel=1e-12)
    cv = MotionFit('iou', TAU_MAX, 3.4e8, 0.5, -1.0, 2.0, 200)
    assert math.isnan(cv.speed_std)
    table = format_motion_fits({'a': walk, 'b': cv})
    assert 'cv end' in table.splitlines()[2] and 'cv end' not in table.splitlines()[1]
