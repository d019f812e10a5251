"""The compiled collar bank against the filterpy reference (issue 12, acceptance 3).

:class:`CollarBank` (all collars in arrays, one compiled loop) must do what one
:class:`CollarFilter` per collar (filterpy) does, fix by fix: the same outcome (accepted,
re-initialised, or the same rejection reason), the same counters, and states equal to
1e-9 m, on generated herds with every fault of the real-collar generator (duty-cycled
intervals, silences of hours, late starts and early ends, outlier bursts, duplicated
stamps, NO_FIX fixes), with every covariance type, and whether the fixes come one collar
after another (offline) or interleaved in arbitrary batches (the node).

Every test runs twice (the ``kernels`` fixture): with the loops compiled by numba at run
time and with the extension compiled ahead of time from the same source
(:mod:`herd_ros.ingest.aot`), the one an installed ``herd-ros ingest`` runs.
"""
import numpy as np
import pandas as pd
import pytest

from herd_ros.ingest.collar_bank import (OUTCOMES, CollarBank, measurement_covariances,
                                         predict_states)
from herd_ros.ingest.collar_filter import (CollarFilter, FilterParams, measurement_covariance,
                                          predict_state)
from herd_ros.ingest.geodesy import geodetic_to_enu
from herd_ros.ingest.pipeline import (auto_filter_params, choose_datum, normalise_fixes,
                                      trajectory_from_fixes)
from herd_ros.synthesis.collar_errors import CollarErrorModel, simulate_collar_fixes
from herd_ros.synthesis.cow_scenario import simulate_cow_herd

TOL_M = 1e-9

pytestmark = pytest.mark.usefixtures('kernels')


@pytest.fixture(scope='module')
def faulty_fixes():
    """Fixes of 5 cows over 2 days with every real-collar fault, more bursts and NO_FIX
    than the defaults, and random NavSatFix covariances of every type (zeros, negative
    and NaN entries included)."""
    truth = simulate_cow_herd(n_cows=5, duration_s=2 * 86400.0, dt=10.0, seed=7)
    model = CollarErrorModel.real_collar(silence_rate=1.0 / 86400.0, burst_rate=1.0 / 60.0,
                                         no_fix_probability=0.02,
                                         duplicate_probability=0.02)
    fixes = normalise_fixes(simulate_collar_fixes(truth, seed=7, model=model))
    rng = np.random.default_rng(7)
    m = len(fixes)
    fixes['position_covariance_type'] = rng.integers(0, 4, m)
    fixes['cov_ee'] = rng.choice([0.0, 4.0, 25.0, 100.0, -1.0, np.nan], m)
    fixes['cov_nn'] = rng.choice([0.0, 9.0, 25.0, 0.1], m)
    fixes['cov_en'] = rng.choice([0.0, 1.5, -2.0, 30.0], m)
    return fixes


def arrays(fixes):
    datum = choose_datum(fixes)
    e, n, _ = geodetic_to_enu(fixes['lat'].to_numpy(), fixes['lon'].to_numpy(),
                              fixes['alt'].to_numpy(), *datum, nan_alt=datum[2])
    cov = np.zeros((len(fixes), 9))
    cov[:, 0] = fixes['cov_ee']
    cov[:, 1] = cov[:, 3] = fixes['cov_en']
    cov[:, 4] = fixes['cov_nn']
    agents = sorted(fixes['agent'].unique())
    idx = pd.Index(agents).get_indexer(fixes['agent'])
    return (agents, idx, fixes['time'].to_numpy(float), e, n,
            fixes['status'].to_numpy(int), fixes['position_covariance_type'].to_numpy(int),
            cov)


def reference(params, agents, order, idx, t, e, n, status, ctype, cov):
    """One CollarFilter per collar over the fixes in ``order``: per-fix outcomes, states
    after accepted fixes, Mahalanobis distances, and the filters."""
    filters = [CollarFilter(params) for _ in agents]
    reasons, xs, Ps, d2 = [], np.full((len(order), 4), np.nan), [], []
    for j, k in enumerate(order):
        f = filters[idx[k]]
        res = f.update(t[k], e[k], n[k], status=status[k], position_covariance=cov[k],
                       position_covariance_type=ctype[k])
        reasons.append(res.reason)
        d2.append(res.mahalanobis2)
        if res.accepted:
            xs[j] = f.x
            Ps.append(f.P.copy())
    return np.array(reasons), xs, np.array(Ps), np.array(d2), filters


def assert_same(params, agents, order, batches, idx, t, e, n, status, ctype, cov):
    reasons, xs, Ps, d2, filters = reference(params, agents, order, idx, t, e, n, status,
                                             ctype, cov)
    bank = CollarBank(len(agents), params)
    outs = []
    for sl in batches:
        rows = order[sl]
        R = bank.measurement_covariances(ctype[rows], cov[rows])
        outs.append(bank.process(idx[rows], t[rows], e[rows], n[rows], status[rows], R))
    outcome = np.concatenate([b.outcome for b in outs])
    got = np.array(OUTCOMES, dtype=object)[outcome]
    mismatch = np.flatnonzero(got != reasons)
    assert not len(mismatch), f'{len(mismatch)} outcomes differ, first at fix ' \
                              f'{mismatch[:1]}: {reasons[mismatch[:1]]} vs {got[mismatch[:1]]}'
    accepted = np.isin(reasons, ['accepted', 'reinitialised'])
    x = np.concatenate([b.x for b in outs])
    P = np.concatenate([b.P for b in outs])
    np.testing.assert_array_equal(np.isnan(x[:, 0]), ~accepted)
    np.testing.assert_allclose(x[accepted], xs[accepted], rtol=0, atol=TOL_M)
    np.testing.assert_allclose(P[accepted], Ps, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.concatenate([b.mahalanobis2 for b in outs]), d2,
                               rtol=1e-9, atol=1e-9, equal_nan=True)
    for i, f in enumerate(filters):
        assert bank.counter_dict(i) == f.counters
        assert (np.isnan(bank.t[i]) and np.isnan(f.t)) or bank.t[i] == f.t
    return reasons


@pytest.mark.parametrize('velocity_tau', [120.0, 0.0])
def test_bank_equals_filterpy_fix_by_fix_on_every_collar_fault(faulty_fixes, velocity_tau):
    params = FilterParams(**auto_filter_params(faulty_fixes, velocity_tau=velocity_tau))
    agents, idx, t, e, n, status, ctype, cov = arrays(faulty_fixes)
    order = np.lexsort((t, idx))                      # offline: collar by collar
    reasons = assert_same(params, agents, order, [slice(None)], idx, t, e, n, status,
                          ctype, cov)
    # the herd really has every case the bank must get right (with a random walk, none of
    # its fixes is refused by the gate alone: the one that was followed a chain adopted
    # past its last fix, test_collar_filter.py)
    seen = set(reasons)
    assert {'accepted', 'reinitialised', 'speed', 'time', 'no_fix', 'unconfirmed'} | (
        {'gate'} if velocity_tau else set()) <= seen, seen


def test_bank_equals_filterpy_with_the_graze_walk_mixture(faulty_fixes):
    """A tight own model with the broad one as its walk component (a fitted collar): the
    GPB1 mixture update of the kernel is the reference's, fix by fix."""
    params = FilterParams(**auto_filter_params(faulty_fixes, accel_std=0.002,
                                               velocity_tau=20.0), walk_accel_std=0.05,
                          walk_velocity_tau=120.0, walk_probability=0.1,
                          walk_position_std=5.0)
    agents, idx, t, e, n, status, ctype, cov = arrays(faulty_fixes)
    order = np.lexsort((t, idx))
    reasons = assert_same(params, agents, order, [slice(None)], idx, t, e, n, status,
                          ctype, cov)
    assert {'accepted', 'gate', 'speed'} <= set(reasons)


def test_bank_equals_filterpy_with_interleaved_batches(faulty_fixes):
    """The node's order: fixes of all collars interleaved (by stamp, ties shuffled) and cut
    into batches of random sizes; short chains and many open candidates."""
    params = FilterParams(**auto_filter_params(faulty_fixes), reacquire_fixes=4,
                          confirm_fixes=2, max_speed=1.5, cruise_speed=0.5)
    agents, idx, t, e, n, status, ctype, cov = arrays(faulty_fixes)
    rng = np.random.default_rng(3)
    order = np.lexsort((rng.random(len(t)), t))
    cuts = np.sort(rng.choice(np.arange(1, len(t)), 40, replace=False))
    batches = [slice(a, b) for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(t)])]
    assert_same(params, agents, order, batches, idx, t, e, n, status, ctype, cov)


def test_bank_equals_filterpy_on_a_chain_its_model_cannot_follow():
    """The adoption of chains whose fixes leave the gate of the track built on them (a lost
    track's first chain, as in ``test_a_chain_its_model_cannot_follow_is_adopted_at_its_
    last_place``, and later a jump chain that moves 300 m within reach halfway), with a
    fix beyond reach and one outside the gate between: the same outcomes and states."""
    params = FilterParams(accel_std=1e-4, velocity_tau=1e5, confirm_fixes_lost=6,
                          default_position_std=5.0, reacquire_fixes=6,
                          reinit_after_gap=1e5, stale_after=1e5)
    t = np.array([0, 60, 120, 420, 480, 540, 600, 660, 700, 720, 780, 800, 860, 920, 1220,
                  1280, 1340, 1400], float)
    e = np.array([0, 0, 0, 400, 400, 400, 400, 400, 3000, 430, 400, 2000, 2000, 2000, 2300,
                  2300, 2300, 2300], float)
    m = len(t)
    reasons = assert_same(params, ['a'], np.arange(m), [slice(None)], np.zeros(m, np.int64),
                          t, e, np.zeros(m), np.zeros(m, np.int64), np.zeros(m, np.int64),
                          np.zeros((m, 9)))
    assert list(reasons[[5, 8, 9, 16, 17]]) == ['accepted', 'speed', 'gate', 'reinitialised',
                                                'accepted']


def test_measurement_covariances_follow_the_reference_rules():
    rng = np.random.default_rng(1)
    m = 2000
    ctype = rng.integers(0, 4, m)
    cov = rng.normal(0, 10, (m, 9))
    cov[rng.random((m, 9)) < 0.05] = np.nan
    cov[::7] = 0.0
    got = measurement_covariances(ctype, cov, 5.0, 0.5)
    want = np.array([measurement_covariance(c, k, 5.0, 0.5) for c, k in zip(cov, ctype)])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    # hand-computed: UNKNOWN -> 25 I; a zero KNOWN covariance floored to 0.25 I;
    # DIAGONAL_KNOWN keeps only the diagonal
    three = measurement_covariances([0, 3, 2], [[1.0] * 9, [0.0] * 9,
                                                [4.0, 7.0, 0, 7.0, 9.0, 0, 0, 0, 0]], 5.0, 0.5)
    np.testing.assert_allclose(three, [25 * np.eye(2), 0.25 * np.eye(2), np.diag([4.0, 9.0])])


def test_predict_states_equals_the_reference_prediction():
    rng = np.random.default_rng(2)
    x = rng.normal(0, 100, (50, 4))
    A = rng.normal(0, 1, (50, 4, 4))
    P = A @ A.transpose(0, 2, 1)
    tau = rng.uniform(0, 600, 50)
    for vt in (0.0, 120.0):
        xo, Po = predict_states(x, P, tau, 0.05, vt)
        xr, Pr = predict_state(x, P, tau, 0.05, vt)
        np.testing.assert_allclose(xo, xr, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(Po, Pr, rtol=1e-12, atol=1e-9)


def test_offline_path_is_the_same_with_either_engine(faulty_fixes):
    for smoother in ('none', 'rts'):
        a = trajectory_from_fixes(faulty_fixes, trim=False, smoother=smoother)
        b = trajectory_from_fixes(faulty_fixes, trim=False, smoother=smoother,
                                  engine='filterpy')
        np.testing.assert_array_equal(np.isnan(a.positions), np.isnan(b.positions))
        np.testing.assert_allclose(a.positions, b.positions, rtol=0, atol=TOL_M,
                                   equal_nan=True)
        assert a.meta['counters'] == b.meta['counters']
        assert (a.meta['fix_outcomes'] == b.meta['fix_outcomes']).all()
