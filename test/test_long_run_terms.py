"""The long-run terms: the space-use (Langevin) field and the stop-and-go noise regimes.

Checked against closed forms (the kernel density of a Gaussian cloud is a Gaussian, so the
field is linear with a known slope), the stationary distribution a simulated law must reach,
parameters of known-truth switching noise, and the model file.
"""
import numpy as np
import pytest

from herd_ros.control.herd_follower import HerdFollower
from herd_ros.errors import HerdInputError
from herd_ros.model.herd_model import AgentLaw, HerdModel
from herd_ros.model.model_file import load_model, save_model
from herd_ros.model.noise_regimes import (RegimeNoise, fit_herd_regimes, fit_regimes,
                                          noise_for, stationary_distribution,
                                          with_noise_regimes)
from herd_ros.model.rbf_field import RbfBasis
from herd_ros.model.space_use_field import space_use_field, with_space_use_field
from herd_ros.simulation.herd_simulator import simulate


def damping_model(damping, q=0.01, dt=1.0, memory=1.0):
    agents = [f'a{k}' for k in range(len(damping))]
    basis = RbfBasis(np.zeros((1, 2)), np.ones(1))
    laws = {a: AgentLaw(damping=d, neighbors=[b for b in agents if b != a],
                        theta1=np.zeros(len(agents) - 1), theta2=np.zeros(len(agents) - 1),
                        basis=basis, field_u=[0.0], field_v=[0.0],
                        noise_cov=q * np.diag([1.0, 0.5]))
            for a, d in zip(agents, damping)}
    return HerdModel(agents=agents, dt=dt, laws=laws, meta={'velocity_memory': memory})


def field_at(basis, fu, fv, info, probe):
    """The whole space-use field at ``probe`` (M, 2): the RBF part plus the home pull."""
    phi = basis.features(probe)
    return (np.column_stack([phi @ fu, phi @ fv])
            - (probe - info['home_center']) @ np.asarray(info['home_gain']).T)


def test_the_field_of_a_gaussian_cloud_is_the_closed_form_linear_pull():
    """Positions ~ N(μ, s²I): the kernel density with bandwidth h is N(μ, (s² + h²)I), so
    (S1) gives g(p) = −Δt/(2(1 − a)) Q (p − μ)/(s² + h²) exactly."""
    rng = np.random.default_rng(1)
    mu, s, h, a, dt = np.array([30.0, -12.0]), 4.0, 1.0, 0.6, 5.0
    q = np.array([[0.02, 0.005], [0.005, 0.01]])
    pts = mu + s * rng.standard_normal((200_000, 2))
    basis, fu, fv, info = space_use_field(pts, a, q, dt, bandwidth=h)
    assert info['bandwidth'] == h
    probe = mu + np.array([[0, 0], [3, 0], [0, -3], [-4, 4], [5, 2]], float)
    got = field_at(basis, fu, fv, info, probe)
    want = -dt / (2 * (1 - a)) * (probe - mu) @ q.T / (s ** 2 + h ** 2)
    scale = np.abs(want).max()
    np.testing.assert_allclose(got, want, atol=0.05 * scale)


def test_a_law_with_the_space_use_field_spends_its_time_where_the_samples_are():
    """The stationary density is the target's: a two-lobed target (70 % / 30 %) and a
    damped law with velocity memory; the simulated agents' time in each lobe and their
    spread match the samples'."""
    rng = np.random.default_rng(2)
    m = 40_000
    lobe = rng.random(m) < 0.7
    target = np.where(lobe[:, None], [0.0, 0.0], [7.0, 0.0]) + 2.0 * rng.standard_normal((m, 2))
    model = damping_model([0.5, 0.5, 0.5], q=0.02, memory=[0.35, 1.0, 1.0])
    stacked = np.repeat(target[:, None, :], 3, axis=1)
    model = with_space_use_field(model, stacked, bandwidth=1.0)
    sim = simulate(model, 80_000, np.zeros((3, 2)), seed=3)
    p = sim.positions[2000:].reshape(-1, 2)
    assert (p[:, 0] > 3.5).mean() == pytest.approx((target[:, 0] > 3.5).mean(), abs=0.04)
    np.testing.assert_allclose(p.mean(0), target.mean(0), atol=0.4)
    # the kernel adds h² = 1 to each axis' variance
    np.testing.assert_allclose(p.std(0), np.sqrt(target.var(0) + 1.0), rtol=0.08)


def test_the_space_use_field_pulls_back_from_far_outside():
    """Far beyond the visited region (where π underflows) the field still points home."""
    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 10, (5000, 2))
    basis, fu, fv, info = space_use_field(pts, 0.5, 0.01 * np.eye(2), 1.0)
    xmin, xmax, ymin, ymax = info['bounds']
    probe = np.array([[xmax - 0.5, 5.0], [xmin + 0.5, 5.0], [5.0, ymax - 0.5], [5.0, ymin + 0.5]])
    g = field_at(basis, fu, fv, info, probe)
    home = np.array([5.0, 5.0]) - probe
    assert ((g * home).sum(1) > 0).all(), g
    # beyond the RBF basis (it vanishes there) the pull is the Ornstein-Uhlenbeck pull of
    # the data's Gaussian, (S2): uniform on [0, 10]² has variance 100/12 per axis
    far = np.array([[400.0, 5.0], [5.0, -300.0], [-250.0, 260.0]])
    phi = basis.features(far)
    assert np.abs(phi @ fu).max() < 1e-12
    want = -1.0 / (2 * 0.5) * 0.01 * (far - 5.0) / (100 / 12)
    np.testing.assert_allclose(field_at(basis, fu, fv, info, far), want,
                               atol=0.03 * np.abs(want).max())


def test_an_agent_far_from_its_range_comes_home_and_stays():
    """A law with the space-use field, started 100 extents away and run with noise whose
    step is a third of the range (a duty-cycled GPS herd): it returns to its range and its
    long-run spread is the data's, not a random walk's (before the home pull (S2), the RBF
    field vanished out there and simulated collared cows drifted 0.5-2 km off)."""
    rng = np.random.default_rng(6)
    pts = rng.uniform(0, 10, (20_000, 2))
    model = damping_model([0.3], q=1.0)               # a step of ~1.4 m s.d. per axis
    model = with_space_use_field(model, pts[:, None, :])
    sim = simulate(model, 20_000, np.array([[1000.0, -800.0]]), seed=7)
    d = np.linalg.norm(sim.positions[:, 0] - 5.0, axis=-1)
    assert d[0] > 1200 and d[2000:].max() < 25.0, (d[2000:].max(), d[-1])
    tail = sim.positions[2000:, 0]
    np.testing.assert_allclose(tail.mean(0), pts.mean(0), atol=0.7)
    # spread: the data's (100/12 per axis) plus the kernel's h², within 15 %
    h = model.meta['space_use_bandwidth'][0]
    np.testing.assert_allclose(tail.var(0), 100 / 12 + h ** 2, rtol=0.15)


def test_space_use_field_refuses_an_unstable_law():
    with pytest.raises(HerdInputError, match='damping < 1'):
        space_use_field(np.random.default_rng(0).standard_normal((100, 2)), 1.0,
                        np.eye(2), 1.0)


def switching_noise(n, cov, trans, seed):
    rng = np.random.default_rng(seed)
    z = np.empty(n, int)
    z[0] = 0
    for t in range(1, n):
        z[t] = rng.choice(len(trans), p=trans[z[t - 1]])
    L = np.linalg.cholesky(cov)
    return np.einsum('tij,tj->ti', L[z], rng.standard_normal((n, 2))), z


def test_baum_welch_recovers_known_switching_noise():
    cov = np.array([np.diag([1e-4, 2e-4]), np.array([[0.04, 0.01], [0.01, 0.02]])])
    trans = np.array([[0.95, 0.05], [0.10, 0.90]])
    w, z = switching_noise(30_000, cov, trans, seed=5)
    w[1000:1200] = np.nan                             # a gap: missing emissions
    fit = fit_regimes(w, 2)
    np.testing.assert_allclose(fit['covariances'], cov, rtol=0.1, atol=2e-5)
    np.testing.assert_allclose(fit['transition'], trans, atol=0.02)
    np.testing.assert_allclose(stationary_distribution(fit['transition']), [2 / 3, 1 / 3],
                               atol=0.03)


def test_bic_keeps_one_regime_for_gaussian_noise_and_two_for_switching():
    rng = np.random.default_rng(6)
    plain = 0.1 * rng.standard_normal((8000, 2, 2))
    assert fit_herd_regimes(plain)['n_regimes'] == 1
    cov = np.array([1e-4 * np.eye(2), 0.03 * np.eye(2)])
    trans = np.array([[0.9, 0.1], [0.2, 0.8]])
    w = np.stack([switching_noise(8000, cov, trans, seed=s)[0] for s in (7, 8)], axis=1)
    assert fit_herd_regimes(w, counts=(1, 2))['n_regimes'] == 2


def test_regime_noise_draws_keep_the_chain_and_its_dwell_time_in_model_steps():
    """Stationary occupancy and the mean dwell time 1/(1 − Π_kk) in model steps, for whole
    steps and for quarter steps (the follower's sub-steps)."""
    cov = np.array([[1e-6 * np.eye(2), np.eye(2)]])
    trans = np.array([[[0.9, 0.1], [0.3, 0.7]]])
    for fraction, n in ((1.0, 20_000), (0.25, 60_000)):
        src = RegimeNoise(cov, trans, rng=9)
        states = np.empty(n, int)
        for t in range(n):
            src.draw(fraction)
            states[t] = src.state[0]
        assert (states == 1).mean() == pytest.approx(0.25, abs=0.025)
        runs = np.diff(np.flatnonzero(np.diff(np.r_[-1, states, -1]) != 0))
        first = states[np.r_[0, np.cumsum(runs)[:-1]]]
        dwell_quiet = runs[first == 0].mean() * fraction
        assert dwell_quiet == pytest.approx(10.0, rel=0.1)


def test_regimes_round_trip_in_the_model_file_and_reach_the_robots(tmp_path):
    model = damping_model([0.5, 0.4], q=0.01)
    cov = np.array([np.array([1e-5 * np.eye(2), 0.03 * np.eye(2)])] * 2)
    trans = np.array([[[0.9, 0.1], [0.2, 0.8]]] * 2)
    # positions of a law whose residuals switch: velocity u' = a u + w
    w = np.stack([switching_noise(6000, cov[0], trans[0], seed=s)[0] for s in (11, 12)], 1)
    u = np.zeros((6000, 2, 2))
    for t in range(1, 6000):
        u[t] = np.array([0.5, 0.4])[:, None] * u[t - 1] + w[t]
    p = np.cumsum(u, axis=0)
    fitted, info = with_noise_regimes(model, [p], counts=(1, 2))
    assert info['n_regimes'] == 2
    got_cov, got_trans = fitted.meta['noise_regimes']
    np.testing.assert_allclose(got_trans, trans, atol=0.04)
    path = tmp_path / 'm.yaml'
    save_model(fitted, path)
    back = load_model(path)
    np.testing.assert_allclose(back.meta['noise_regimes'][0], got_cov)
    np.testing.assert_allclose(back.meta['noise_regimes'][1], got_trans)
    assert isinstance(noise_for(back, 0), RegimeNoise)
    follower = HerdFollower(back, ['a1', 'a1', 'a0'], noise=True, seed=1)
    assert isinstance(follower.noise_source, RegimeNoise)
    np.testing.assert_allclose(follower.noise_source.transition[1], got_trans[1])
    # a file whose regimes do not fit together gets one clear error
    text = path.read_text().replace('noise_regime_transition: [', 'noise_regime_transition: [0.5, ')
    path.write_text(text)
    with pytest.raises(HerdInputError, match='noise_regime'):
        load_model(path)


def test_the_home_pull_round_trips_in_the_model_file_and_reaches_the_robots(tmp_path):
    """Two agents with ranges 1 km apart: the file keeps their home pulls, and a robot on
    agent a1, placed far from both, is pulled towards a1's range, not a0's."""
    rng = np.random.default_rng(9)
    pts = np.stack([rng.uniform(0, 10, (4000, 2)), 1000.0 + rng.uniform(0, 10, (4000, 2))], 1)
    model = with_space_use_field(damping_model([0.5, 0.5], q=0.01), pts)
    path = tmp_path / 'home.yaml'
    save_model(model, path)
    back = load_model(path)
    np.testing.assert_allclose(back.meta['space_use_home'][0], model.meta['space_use_home'][0])
    np.testing.assert_allclose(back.meta['space_use_home'][1], model.meta['space_use_home'][1])
    far = np.array([[-3000.0, 500.0], [-3000.0, 500.0]])
    np.testing.assert_allclose(back.environment(far), model.environment(far))
    follower = HerdFollower(back, ['a1', 'a0'], noise=False)
    g = follower.model.environment(far)
    for k, home in enumerate(([1005.0, 1005.0], [5.0, 5.0])):
        to_home = (np.array(home) - far[k]) / np.linalg.norm(np.array(home) - far[k])
        assert g[k] @ to_home > 0.99 * np.linalg.norm(g[k]), (k, g[k], to_home)
    text = path.read_text().replace('space_use_home_gain: [', 'space_use_home_gain: [0.5, ')
    path.write_text(text)
    with pytest.raises(HerdInputError, match='space_use_home'):
        load_model(path)


def test_an_agent_without_enough_data_keeps_its_fitted_field_and_gaussian_noise():
    """Bad input loses nothing: an agent with two positions keeps its fitted field (and the
    reason is recorded); one with a handful of residuals keeps Gaussian noise while the
    others get their regimes."""
    model = damping_model([0.5, 0.5], q=0.01)
    rng = np.random.default_rng(13)
    p = rng.standard_normal((3000, 2, 2)).cumsum(0) * 0.01
    p[2:, 1] = np.nan                                   # agent a1: two positions only
    out = with_space_use_field(model, p)
    assert out.laws['a1'].basis.size == 1 and 'a1' in out.meta['space_use_kept_fitted']
    assert out.laws['a0'].basis.size > 1 and 'a0' not in out.meta['space_use_kept_fitted']
    cov = np.array([1e-5 * np.eye(2), 0.03 * np.eye(2)])
    trans = np.array([[0.9, 0.1], [0.2, 0.8]])
    w = np.full((5000, 2, 2), np.nan)
    w[:, 0] = switching_noise(5000, cov, trans, seed=14)[0]
    w[:8, 1] = 0.1 * rng.standard_normal((8, 2))        # a1: 8 residuals
    fit = fit_herd_regimes(w, counts=(1, 2))
    assert fit['n_regimes'] == 2 and fit['too_few'] == [1]
    flat = fit['agents'][1]['covariances']
    np.testing.assert_allclose(flat[0], flat[1])


def test_an_agent_that_never_moved_keeps_gaussian_noise_and_the_others_their_regimes():
    """All-zero residuals (a calibration collar at rest, a fix repeated) gave the
    compiled Baum-Welch a singular covariance and a ZeroDivisionError that stopped the
    fit; now that agent is one with too few residuals: flat regimes, no BIC share."""
    cov = np.array([1e-5 * np.eye(2), 0.03 * np.eye(2)])
    trans = np.array([[0.9, 0.1], [0.2, 0.8]])
    w = np.zeros((5000, 2, 2))
    w[:, 0] = switching_noise(5000, cov, trans, seed=15)[0]
    fit = fit_herd_regimes(w, counts=(1, 2))
    assert fit['n_regimes'] == 2 and fit['too_few'] == [1]
    assert all(np.isfinite(v) for v in fit['bic'].values())
    with pytest.raises(HerdInputError, match='all zero'):
        fit_regimes(np.zeros((200, 2)), 2)


def test_the_home_gain_is_the_closed_form():
    # K = Δt/(2(1 − a)) Q Σ⁻¹ (S2), two agents at once: Σ = diag(4, 1), Q = diag(0.1, 0.2),
    # a = 0.9, Δt = 2 → 10 · diag(0.025, 0.2); the second agent's axes swapped
    from herd_ros.model.space_use_field import home_gain
    sigma = np.array([np.diag([4.0, 1.0]), np.diag([1.0, 4.0])])
    q = np.array([np.diag([0.1, 0.2]), np.diag([0.2, 0.1])])
    k = home_gain(sigma, np.array([0.9, 0.9]), q, 2.0)
    np.testing.assert_allclose(k[0], np.diag([0.25, 2.0]))
    np.testing.assert_allclose(k[1], np.diag([2.0, 0.25]))


def test_the_online_estimator_keeps_each_animals_range(tmp_path):
    # the live home pull: the running mean and covariance of each animal's positions (with
    # the forgetting factor's weights), none before 10 positions; kept by checkpoints
    from herd_ros.estimation.online_fit import MIN_HOME_POSITIONS, OnlineHerdEstimator
    from herd_ros.model.discrete_gain import discrete_gain
    rng = np.random.default_rng(3)
    steps = 200
    p = np.stack([rng.normal([10.0, -5.0], [3.0, 1.0], (steps, 2)),
                  rng.normal([-20.0, 40.0], [1.0, 2.0], (steps, 2))], axis=1)
    p[50:60, 1] = np.nan                          # the second animal missing a while
    est = OnlineHerdEstimator(['a', 'b'], 1.0, law='shared', field_grid=(2, 2),
                              field_bounds=(-50, 50, -50, 50))
    for k in range(MIN_HOME_POSITIONS - 1):
        est.add_snapshot(float(k), p[k])
    assert not est.home_pull()[1].any() and 'space_use_home' not in est.model().meta
    for k in range(MIN_HOME_POSITIONS - 1, steps):
        est.add_snapshot(float(k), p[k])
    a = est.theta[:, 0]
    q = est.rls.noise_cov()
    mu, gain, cov = est.home_pull()
    for i in range(2):
        pts = p[np.isfinite(p[:, i]).all(axis=1), i]
        np.testing.assert_allclose(mu[i], pts.mean(axis=0))
        np.testing.assert_allclose(cov[i], np.cov(pts.T, bias=True), rtol=1e-9)
        expected = 1.0 / (2.0 * (1.0 - a[i])) * q[i] @ np.linalg.inv(np.cov(pts.T, bias=True))
        # (S2) on these moments, made exact on the clock by (G1) (test_discrete_gain.py)
        np.testing.assert_allclose(gain[i], discrete_gain(expected[None], a[i:i + 1], 1.0)[0],
                                   rtol=1e-9, atol=1e-12)
    # each one's place in the herd: its offset from the other (here: one other)
    both = np.isfinite(p).all(axis=(1, 2))
    d = p[both, 0] - p[both, 1]
    m, k, s = est.herd_place()
    np.testing.assert_allclose(m, [d.mean(0), -d.mean(0)])
    np.testing.assert_allclose(s[0], np.cov(d.T, bias=True), rtol=1e-9)
    # in the model (for its law's damping), and through its file
    from herd_ros.model.kinds import load, save
    model = est.model()
    theta = est.pruned_estimate(est.kept_centers())[0]
    again_model = load(save(model, tmp_path / 'm.yaml'))
    for key, want in (('space_use_home', est.home_pull(theta)),
                      ('herd_place', est.herd_place(theta))):
        for got in (model.meta[key], again_model.meta[key]):
            for x, y in zip(got, want):
                np.testing.assert_allclose(x, y, rtol=1e-9)
    path = est.save_checkpoint(tmp_path / 'c.npz')
    again = OnlineHerdEstimator(['a', 'b'], 1.0, law='shared', field_grid=(2, 2),
                                field_bounds=(-50, 50, -50, 50))
    assert again.load_checkpoint(path)
    np.testing.assert_allclose(again.home_pull()[0], mu)
    # forgetting λ: position k of n weighs λ^(n−1−k)
    lam = 0.99
    est = OnlineHerdEstimator(['a', 'b'], 1.0, law='shared', field_grid=(2, 2),
                              field_bounds=(-50, 50, -50, 50), forgetting=lam)
    for k in range(steps):
        est.add_snapshot(float(k), p[k])
    w = lam ** np.arange(steps - 1, -1, -1.0)
    np.testing.assert_allclose(est.home_pull()[0][0], (w[:, None] * p[:, 0]).sum(0) / w.sum())


def test_the_range_edge_pull_is_zero_inside_and_the_gain_on_the_excess_beyond():
    # home_drift with a range Σ: −K (p − μ)(1 − 2/r)₊, r the Mahalanobis distance; Σ =
    # diag(4, 1) (std 2 m and 1 m), K = 0.1 I, μ = (10, 0)
    from herd_ros.model.space_use_field import home_drift
    meta = {'space_use_home': (np.array([[10.0, 0.0]]), 0.1 * np.eye(2)[None],
                               np.diag([4.0, 1.0])[None])}
    inside = np.array([[[13.9, 0.0]], [[10.0, 1.9]], [[11.0, 1.0]]])   # r = 1.95, 1.9, 1.1
    assert np.allclose(home_drift(meta, inside), 0.0)
    # 8 m east: r = 4, half of the linear pull −0.1 · 8; 3 m north: r = 3, a third of −0.3
    np.testing.assert_allclose(home_drift(meta, np.array([[18.0, 0.0]])), [[-0.4, 0.0]])
    np.testing.assert_allclose(home_drift(meta, np.array([[10.0, 3.0]])), [[0.0, -0.1]])
    # without a range: the linear pull (S2) everywhere
    np.testing.assert_allclose(home_drift({'space_use_home': meta['space_use_home'][:2]},
                                          np.array([[11.0, 0.0]])), [[-0.1, 0.0]])


def test_each_agents_place_in_the_herd_is_its_offset_from_the_others():
    # c_−i by hand (one agent missing), the offsets' moments, and the edge pull in the herd's
    # frame: a whole herd moving together feels nothing, one agent leaving its place does
    from herd_ros.model.herd_place import herd_place, others_centroid, place_drift
    p = np.array([[0.0, 0.0], [4.0, 0.0], [np.nan, np.nan], [2.0, 6.0]])
    np.testing.assert_allclose(others_centroid(p)[[0, 1, 3]], [[3.0, 3.0], [1.0, 3.0],
                                                                [2.0, 0.0]])
    assert np.isfinite(others_centroid(p)[2]).all()        # a missing agent's others exist
    rng = np.random.default_rng(0)
    steps = 4000
    drift = np.cumsum(rng.normal(0.0, 2.0, (steps, 1, 2)), axis=0)       # the herd travels
    slots = np.array([[-10.0, 0.0], [10.0, 0.0], [0.0, 15.0]])
    wobble = rng.normal(0.0, 1.0, (steps, 3, 2))
    positions = drift + slots + wobble
    # noise small against the places (small steps): the gain is (S2)'s 5 Q Σ⁻¹
    mean, gain, cov = herd_place(positions, np.full(3, 0.9),
                                 np.tile(1e-4 * np.eye(2), (3, 1, 1)), 1.0)
    d = positions - (positions.sum(1, keepdims=True) - positions) / 2.0
    for i in range(3):
        np.testing.assert_allclose(mean[i], d[:, i].mean(0))
        np.testing.assert_allclose(cov[i], np.cov(d[:, i].T, bias=True), rtol=1e-9)
        small_step = 5e-4 * np.linalg.inv(cov[i])
        np.testing.assert_allclose(gain[i], small_step, atol=0.02 * np.abs(small_step).max())
    # noise that no pull can hold to these places at this clock (K Δt of (S2) ≈ 3.4, beyond
    # the loop's stability edge 1 − a = 0.1): the tightest stable gain instead (G1)
    _, loud, _ = herd_place(positions, np.full(3, 0.9), np.tile(np.eye(2), (3, 1, 1)), 1.0)
    for i in range(3):
        c = np.real(np.linalg.eigvals(loud[i]))
        assert (c > 0).all() and (c < 0.1).all()
    meta = {'herd_place': (mean, gain, cov)}
    at_slots = (slots - slots.mean(0))[None] + np.array([[500.0, -300.0]])
    assert np.allclose(place_drift(meta, at_slots), 0.0, atol=1e-9)
    away = at_slots.copy()
    away[0, 0] += [-40.0, 0.0]                                # agent 0 runs 40 m west
    g = place_drift(meta, away)[0]
    assert g[0, 0] > 0.0 and abs(g[0, 1]) < 0.2 * g[0, 0]     # pulled back east
    assert (g[1:, 0] < 0.0).all()                             # the others lean after it


def test_a_law_with_its_herd_places_keeps_a_travelling_herd_together():
    # three agents of damping and noise alone random-walk apart; with the places learned
    # from a cohesive herd their mutual distances stay those of the herd while the herd as a
    # whole still wanders (a home range would not hold it: it has none)
    import dataclasses

    from herd_ros.model.herd_place import herd_place
    model = damping_model([0.8, 0.8, 0.8], q=0.02)
    rng = np.random.default_rng(1)
    steps = 3000
    herd = (np.cumsum(rng.normal(0.0, 0.3, (steps, 1, 2)), axis=0)
            + np.array([[-5.0, 0.0], [5.0, 0.0], [0.0, 8.0]]) + rng.normal(0, 1.0, (steps, 3, 2)))
    q = np.stack([model.laws[a].noise_cov for a in model.agents])
    place = herd_place(herd, model.damping, q, model.dt)
    kept = dataclasses.replace(model, meta={**model.meta, 'herd_place': place})

    def spread(m, seed):
        run = simulate(m, 20000, herd[0], seed=seed)
        p = run.positions[-10000:]
        return np.linalg.norm(p[:, :, None] - p[:, None], axis=-1).max(axis=(1, 2)).mean()
    data = np.linalg.norm(herd[:, :, None] - herd[:, None], axis=-1).max(axis=(1, 2)).mean()
    free, together = spread(model, 3), spread(kept, 3)
    assert free > 3.0 * data, (free, data)
    assert abs(together - data) < 0.35 * data, (together, data)


def test_an_estimator_without_range_pulls_publishes_none():
    # range_pulls=False (the estimator parameter): the ranges are still measured, the gains
    # are zero and the model carries neither pull
    from herd_ros.estimation.online_fit import OnlineHerdEstimator
    rng = np.random.default_rng(4)
    est = OnlineHerdEstimator(['a', 'b', 'c'], 1.0, law='shared', field_grid=(2, 2),
                              field_bounds=(-50, 50, -50, 50), range_pulls=False)
    for k in range(100):
        est.add_snapshot(float(k), rng.normal(0.0, 5.0, (3, 2)))
    theta, home, place = est.published_law()
    assert not home[1].any() and not place[1].any() and home[2].any()
    assert 'space_use_home' not in est.model().meta and 'herd_place' not in est.model().meta


def test_a_fitted_laws_place_pull_is_capped_at_a_fifth_of_its_noise_and_still_holds():
    # (P2): with_herd_place caps each pull at 0.2 σ_i, σ_i² the largest eigenvalue of the
    # noise the law draws (here Q = 0.02 diag(1, 0.5), its free-run factor 0.5 on the std:
    # σ = 0.5 √0.02); inside the range nothing, just beyond it the uncapped (P1), far beyond
    # 0.2 σ in the direction of (P1); and the capped places still keep the travelling herd of the
    # test above together
    import dataclasses

    from herd_ros.model.herd_place import PLACE_CAP, place_drift, with_herd_place
    model = damping_model([0.8, 0.8, 0.8], q=0.02)
    model = dataclasses.replace(model, meta={**model.meta, 'noise_scale': np.full(3, 0.5)})
    rng = np.random.default_rng(1)
    steps = 3000
    herd = (np.cumsum(rng.normal(0.0, 0.3, (steps, 1, 2)), axis=0)
            + np.array([[-5.0, 0.0], [5.0, 0.0], [0.0, 8.0]]) + rng.normal(0, 1.0, (steps, 3, 2)))
    placed = with_herd_place(model, herd)
    mean, gain, cov, cap = placed.meta['herd_place']
    sigma = 0.5 * np.sqrt(0.02)
    assert PLACE_CAP == 0.2
    np.testing.assert_allclose(cap, 0.2 * sigma, rtol=1e-12)
    uncapped = {'herd_place': (mean, gain, cov)}
    slots = mean * 2.0 / 3.0        # positions whose offsets are their means (N = 3): inside
    assert np.allclose(place_drift(placed.meta, slots), 0.0)
    far = slots.copy()
    far[0] += [-60.0, 0.0]
    g, g0 = place_drift(placed.meta, far), place_drift(uncapped, far)
    assert (np.linalg.norm(g, axis=-1) <= cap * (1 + 1e-12)).all()
    assert np.isclose(np.linalg.norm(g[0]), cap[0])             # agent 0 is far out: capped
    np.testing.assert_allclose(g[0] / np.linalg.norm(g[0]), g0[0] / np.linalg.norm(g0[0]))
    # just beyond the edge the pull is below its cap: (P1) itself
    near = slots.copy()
    near[0] += [-2.05 * np.sqrt(cov[0, 0, 0]), 0.0]
    small = place_drift(uncapped, near)
    assert 0.0 < np.linalg.norm(small[0]) < cap[0]
    np.testing.assert_allclose(place_drift(placed.meta, near), small)

    def spread(m, seed):
        run = simulate(m, 20000, herd[0], seed=seed)
        p = run.positions[-10000:]
        return np.linalg.norm(p[:, :, None] - p[:, None], axis=-1).max(axis=(1, 2)).mean()
    data = np.linalg.norm(herd[:, :, None] - herd[:, None], axis=-1).max(axis=(1, 2)).mean()
    assert spread(model, 3) > 3.0 * data
    assert abs(spread(placed, 3) - data) < 0.35 * data, (spread(placed, 3), data)


def test_the_place_cap_goes_through_the_model_file(tmp_path):
    import dataclasses

    from herd_ros.model.herd_place import with_herd_place
    model = damping_model([0.8, 0.8, 0.8], q=0.02)
    rng = np.random.default_rng(2)
    herd = np.array([[-5.0, 0.0], [5.0, 0.0], [0.0, 8.0]]) + rng.normal(0, 1.0, (500, 3, 2))
    placed = with_herd_place(model, herd)
    path = tmp_path / 'm.yaml'
    save_model(placed, path)
    back = load_model(path)
    for x, y in zip(back.meta['herd_place'], placed.meta['herd_place'], strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-9)
    # a cap without the place, or of the wrong length, is refused
    import yaml
    doc = yaml.safe_load(path.read_text())
    body = doc['/**']['ros__parameters']['model']
    for key in ('herd_place_offset', 'herd_place_gain', 'herd_place_range'):
        del body[key]
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(HerdInputError, match='herd_place_cap'):
        load_model(path)
    save_model(dataclasses.replace(placed, meta={**placed.meta, 'herd_place': (
        *placed.meta['herd_place'][:3], np.ones(2))}), path)
    with pytest.raises(HerdInputError, match='herd_place_cap'):
        load_model(path)


def test_the_fit_keeps_the_places_of_a_herd_its_law_lets_drift_apart():
    # three animals that keep their places (1 m about fixed slots) while the herd wanders:
    # the law learned is damping and noise alone, which run freely random-walk apart; on the
    # validation tail the places bring the free run's distance back, at no cost one step
    # ahead, so the default fit keeps them (and --herd-place off does not)
    from herd_ros.herd_dynamics import FitOptions, HerdDynamics
    from herd_ros.simulation.free_run import free_run_fidelity
    from herd_ros.trajectory import HerdTrajectory
    rng = np.random.default_rng(1)
    steps = 4000
    herd = (np.cumsum(rng.normal(0.0, 0.3, (steps, 1, 2)), axis=0)
            + np.array([[-5.0, 0.0], [5.0, 0.0], [0.0, 8.0]]) + rng.normal(0, 1.0, (steps, 3, 2)))
    run = HerdTrajectory(np.arange(steps, dtype=float), ['a', 'b', 'c'], herd)
    train, test = HerdTrajectory(run.times[:3000], run.agents, herd[:3000]), \
        HerdTrajectory(run.times[3000:], run.agents, herd[3000:])
    opts = dict(terms=['damping'], field='fitted', noise='gaussian', noise_scale=1.0)
    kept = HerdDynamics(options=FitOptions(**opts)).fit(train)
    off = HerdDynamics(options=FitOptions(**opts, place='off')).fit(train)
    assert kept.choices['herd_place'] and kept.choices['place_choice']['kept']
    assert not off.choices['herd_place'] and 'herd_place' not in (off.model.meta or {})
    far = free_run_fidelity(off.model, test)['herd']['distance']
    held = free_run_fidelity(kept.model, test)['herd']['distance']
    assert far['relative'] > 0.5, far
    assert abs(held['relative']) < 0.35, held


def test_the_place_centroid_counts_only_the_agents_asked_for():
    """By hand: three agents at (0, 0), (4, 0) and (1000, 0). Counting all, the first's
    others' centroid is (502, 0); with the third left out it is (4, 0); the third's own
    offset is still taken, from the centroid of the two counted."""
    from herd_ros.model.herd_place import others_centroid, place_offsets
    p = np.array([[0.0, 0.0], [4.0, 0.0], [1000.0, 0.0]])
    np.testing.assert_allclose(others_centroid(p)[0], [502.0, 0.0])
    counted = np.array([True, True, False])
    np.testing.assert_allclose(others_centroid(p, counted), [[4.0, 0.0], [0.0, 0.0],
                                                             [2.0, 0.0]])
    np.testing.assert_allclose(place_offsets(p, counted)[2], [998.0, 0.0])


def test_a_robot_whose_animal_is_out_of_the_herd_does_not_pull_the_others():
    """Two robots at their animals' places (4 m apart) and a third 1.3 km off whose animal
    has no pose: the third moves neither robot's place pull; counted (its animal back in
    the herd), it drags both towards it."""
    import dataclasses

    from herd_ros.model.rbf_field import agent_fields
    from herd_ros.synthesis.known_truth import make_truth_model
    truth = make_truth_model(3, seed=1)
    # each animal's place: offset (-2, 0), (2, 0), (0, 0) from the others' centroid; ranges
    # of 1 m std; gain 0.1 per step
    mean = np.array([[-2.0, 0.0], [2.0, 0.0], [0.0, 0.0]])
    gain = np.tile(0.1 * np.eye(2), (3, 1, 1))
    cov = np.tile(np.eye(2), (3, 1, 1))
    model = dataclasses.replace(truth, meta={'herd_place': (mean, gain, cov)})
    follower = HerdFollower(model, list(model.agents))
    m = follower.model
    p = np.array([[0.0, 0.0], [4.0, 0.0], [1300.0, 0.0]])
    active = np.ones(3, dtype=bool)

    def place_pull():
        return follower.environment(p, active) - agent_fields(p, m._centers, m._sigma,
                                                              m._coef)
    follower.in_herd = np.array([True, True, False])
    np.testing.assert_allclose(place_pull()[:2], 0.0, atol=1e-12)    # at their places
    follower.in_herd[:] = True
    assert (place_pull()[:2, 0] > 1.0).all()                         # dragged east


def test_a_range_that_has_not_spread_pulls_nothing_and_warns_nothing():
    """An animal seen at one place so far (Σ = 0, gain 0) beside one with a range of 1 m
    std and gain 0.1: the first is pulled by nothing however far it is, with no overflow
    warning; the second, 3 m out, by 0.1 × 3 × (1 − 2/3) = 0.1 towards its centre."""
    import warnings

    from herd_ros.model.space_use_field import edge_pull
    cov = np.stack([np.zeros((2, 2)), np.eye(2)])
    gain = np.stack([np.zeros((2, 2)), 0.1 * np.eye(2)])
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        pull = edge_pull(np.array([[1e3, 5.0], [3.0, 0.0]]), gain, cov)
    np.testing.assert_allclose(pull, [[0.0, 0.0], [-0.1, 0.0]], atol=1e-12)
