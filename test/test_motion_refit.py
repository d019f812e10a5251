"""The causal refit schedule of the collar motion models (:mod:`herd_ros.ingest.motion_refit`).

The node and the offline path refit at the same fixes whatever the batching: checked here
on the bank driven in random batches against the whole file at once (and, in
``test_gps_ingest_node.py``, on the running node against ``herd-ros ingest``'s path).
"""
import numpy as np
import pandas as pd
import pytest

from herd_ros.ingest import collar_bank
from herd_ros.ingest.collar_filter import FilterParams
from herd_ros.ingest.motion_refit import (MotionRefitter, RefitConfig, fix_variance,
                                          process_with_refits, refit_due, stabbing_cuts)
from herd_ros.ingest.pipeline import (DEFAULT_WALK_ACCEL_STD, auto_filter_params,
                                      fixes_enu, refit_config,
                                      trajectory_from_fixes, with_walk)
from herd_ros.synthesis.collar_errors import CollarErrorModel, simulate_collar_fixes
from herd_ros.synthesis.cow_scenario import simulate_cow_herd


def test_the_schedule_doubles_then_steps():
    due = np.flatnonzero(refit_due(np.arange(1, 4000), first=20, max_interval=1000)) + 1
    assert due.tolist() == [20, 40, 80, 160, 320, 640, 1640, 2640, 3640]


def test_a_window_keeps_each_collars_last_accepted_fixes_in_order():
    rng = np.random.default_rng(0)
    r = MotionRefitter(3, RefitConfig(window=5))
    kept = {i: [] for i in range(3)}
    for _ in range(30):
        m = int(rng.integers(1, 40))
        c = rng.integers(0, 3, m)
        t = rng.random(m)
        ok = rng.random(m) < 0.7
        r.observe(c, t, t, -t, np.full(m, np.nan), ok)
        for ci, ti, a in zip(c, t, ok):
            if a:
                kept[int(ci)].append(ti)
    for i in range(3):
        t, z, _ = r.window(i)
        np.testing.assert_array_equal(t, kept[i][-5:])
        np.testing.assert_array_equal(z[:, 1], -np.asarray(kept[i][-5:]))
    assert r.seen.sum() > 0


def test_the_fewest_cuts_stab_every_interval():
    # refit points after positions 0, 3, 4 of collars 0, 2, 1, each before its collar's
    # next fix (2, 6, 8): the intervals (0, 2], (3, 6], (4, 8]; (3, 6] and (4, 8] share one
    lo, hi = [0, 3, 4], [2, 6, 8]
    cuts = stabbing_cuts(lo, hi)
    assert cuts == [2, 6]
    assert all(any(a < c <= b for c in cuts) for a, b in zip(lo, hi))
    rng = np.random.default_rng(3)
    for _ in range(50):
        lo = rng.integers(0, 100, 20)
        hi = lo + rng.integers(1, 30, 20)
        cuts = stabbing_cuts(lo, hi)
        assert all(any(a < c <= b for c in cuts) for a, b in zip(lo, hi))
        # no cut can go: each is the only one in some interval
        for c in cuts:
            rest = [d for d in cuts if d != c]
            assert not all(any(a < d <= b for d in rest) for a, b in zip(lo, hi))


@pytest.fixture(scope='module')
def collared_cows():
    truth = simulate_cow_herd(n_cows=3, duration_s=36 * 3600.0, dt=10.0, seed=4)
    raw = simulate_collar_fixes(truth, seed=4, model=CollarErrorModel.real_collar())
    return raw


@pytest.mark.parametrize('engine', ['bank', 'filterpy'])
def test_a_refit_filters_from_the_first_fix_stamped_its_lag_after_it(engine):
    """One collar, a fix every 10 s: its model changes exactly at the first fix stamped at
    least ``lag_s`` after its 20th, 40th and 80th fix (the refit points), and nowhere
    else; with no lag, at the very next fix."""
    if engine == 'bank' and not collar_bank.AVAILABLE:
        pytest.skip('no compiled kernels')
    rng = np.random.default_rng(5)
    k = 160
    t = 1000.0 + 10.0 * np.arange(k) + rng.uniform(0, 2, k)
    xy = np.cumsum(rng.normal(0, 1.0, (k, 2)), axis=0) + rng.normal(0, 3.0, (k, 2))
    fixes = pd.DataFrame({'time': t, 'agent': 'c', 'x': xy[:, 0], 'y': xy[:, 1]})
    from herd_ros.ingest.pipeline import planar_fixes
    for lag in (0.0, 45.0, 300.0):
        traj = trajectory_from_fixes(planar_fixes(fixes), 10.0, engine=engine, trim=False,
                                     motion_model='fit', refit_lag_s=lag)
        tl = traj.meta['timelines']['c']
        assert tl.t.tolist() == t[1:].tolist()       # every fix a state (the 1st confirms)
        changes = np.flatnonzero((np.diff(tl.motion, axis=0) != 0).any(axis=1)) + 1
        # the first fix after the n-th stamped at least lag after it
        expect = [t[n + int(np.argmax(t[n:] >= t[n - 1] + lag))] for n in (20, 40, 80)]
        assert tl.t[changes].tolist() == expect, (lag, tl.t[changes], expect)


@pytest.mark.skipif(not collar_bank.AVAILABLE, reason='no compiled kernels')
@pytest.mark.parametrize('lag', [0.0, 60.0, 5000.0])
def test_the_refits_do_not_depend_on_the_batching(collared_cows, lag):
    """Fixes in stamp order, cut into random batches (the node), give the states of the
    whole file at once (the offline rounds), whatever the refits' lag (5000 s: several
    refits of a collar waiting to take over at once)."""
    raw = collared_cows
    datum = raw.attrs['datum']
    offline = trajectory_from_fixes(raw, datum=datum, trim=False, motion_model='fit',
                                    refit_lag_s=lag)
    params = with_walk(FilterParams(**auto_filter_params(raw)), DEFAULT_WALK_ACCEL_STD)
    agents = list(offline.agents)
    fixes = raw.sort_values('time', kind='stable').reset_index(drop=True)
    e, n = fixes_enu(fixes, datum)
    cov = np.zeros((len(fixes), 9))
    cov[:, 0], cov[:, 4] = fixes['cov_ee'], fixes['cov_nn']
    cov[:, 1] = cov[:, 3] = fixes['cov_en']
    ctype = fixes['position_covariance_type'].to_numpy(int)
    idx = pd.Index(agents).get_indexer(fixes['agent'])
    bank = collar_bank.CollarBank(len(agents), params)
    refitter = MotionRefitter(len(agents), refit_config(params, lag_s=lag))
    var = fix_variance(ctype, cov[:, 0], cov[:, 4], params.position_std_floor)
    rng = np.random.default_rng(1)
    cuts = np.sort(rng.choice(np.arange(1, len(fixes)), 60, replace=False))
    t = fixes['time'].to_numpy(float)
    status = fixes['status'].to_numpy(int)
    xs = []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(fixes)]):
        sl = slice(a, b)
        batch, _ = process_with_refits(bank, refitter, idx[sl], t[sl], e[sl], n[sl],
                                       status[sl], ctype[sl], cov[sl], var[sl])
        xs.append(batch.x)
    x = np.concatenate(xs)
    assert refitter.refits >= 3 * 4
    for i, agent in enumerate(agents):
        mine = idx == i
        got = x[mine][np.isfinite(x[mine][:, 0])]
        want = offline.meta['timelines'][agent].x
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
        mine, theirs = refitter.fits[i], offline.meta['motion_fits'][agent]
        assert mine.model == theirs.model
        np.testing.assert_array_equal(
            [mine.velocity_tau, mine.diffusion, mine.position_std, mine.loglik],
            [theirs.velocity_tau, theirs.diffusion, theirs.position_std, theirs.loglik])
