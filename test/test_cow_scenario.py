"""The realistic cow herd: invariants checked from the positions themselves.

Containment is checked by hand (the default paddock is a box) and with matplotlib's
point-in-polygon on a non-convex paddock; speeds, spacing and cohesion are computed from the
positions; behaviour budgets against the typical figures the module documents.
"""
import numpy as np
import pytest
from matplotlib.path import Path

from herd_ros.errors import HerdInputError
from herd_ros.synthesis.cow_scenario import (GRAZING, RESTING, WALKING, Paddock,
                                             simulate_cow_herd, solar_hour)
from herd_ros.trajectory import HerdTrajectory

L_FENCE = np.array([[0, 0], [160, 0], [160, 60], [60, 60], [60, 140], [0, 140]], float)


@pytest.fixture(scope='module')
def hour_herd():
    """The demo case: 3 cows, 1 h at 1 Hz."""
    return simulate_cow_herd(n_cows=3, duration_s=3600.0, dt=1.0, seed=0)


@pytest.fixture(scope='module')
def day_herds():
    """Two whole days (4 cows, 5 s steps), so every time of day is covered."""
    return [simulate_cow_herd(n_cows=4, duration_s=86400.0, dt=5.0, seed=s) for s in (1, 2)]


@pytest.fixture(scope='module')
def l_paddock_herd():
    paddock = Paddock(fence=L_FENCE, water=[[150.0, 10.0]], shade=[[20.0, 120.0]])
    return simulate_cow_herd(n_cows=5, duration_s=6 * 3600.0, dt=2.0, seed=3,
                             paddock=paddock, start_time=7 * 3600.0)


def speeds(traj):
    return np.linalg.norm(np.diff(traj.positions, axis=0), axis=-1) / np.diff(traj.times)[:, None]


def pair_distances(traj):
    i, j = np.triu_indices(traj.n_agents, 1)
    return np.linalg.norm(traj.positions[:, i] - traj.positions[:, j], axis=-1)


def test_shape_ids_and_clock(hour_herd):
    assert isinstance(hour_herd, HerdTrajectory)
    assert hour_herd.agents == ['cow_1', 'cow_2', 'cow_3']
    assert hour_herd.positions.shape == (3600, 3, 2)
    np.testing.assert_allclose(hour_herd.times, np.arange(3600.0))
    assert np.isfinite(hour_herd.positions).all()
    assert hour_herd.meta['state'].shape == (3600, 3)


def test_default_paddock_never_left(hour_herd, day_herds):
    for traj in [hour_herd, *day_herds]:
        x, y = traj.positions[..., 0], traj.positions[..., 1]
        assert (x > -200).all() and (x < 200).all() and (y > -150).all() and (y < 150).all()


def test_non_convex_paddock_never_left(l_paddock_herd):
    pts = l_paddock_herd.positions.reshape(-1, 2)
    assert Path(L_FENCE).contains_points(pts).all()
    # the notch (x > 60, y > 60) is outside: nobody may be there
    assert not ((pts[:, 0] > 60.5) & (pts[:, 1] > 60.5)).any()
    # the herd did meet the fence, so the check is not vacuous
    near = (pts[:, 0] < 3) | (pts[:, 1] < 3) | (pts[:, 0] > 157) | (pts[:, 1] > 137)
    assert near.any()


def test_speeds_are_those_of_cattle(hour_herd, day_herds):
    for traj in [hour_herd, *day_herds]:
        v = speeds(traj)
        assert np.median(v) < 0.3
        assert np.percentile(v, 95) < 1.5
        assert v.max() < 2.5
        still = (v < 0.02).mean()
        assert 0.1 < still < 0.8
    v = np.concatenate([speeds(t).ravel() for t in day_herds])
    state = np.concatenate([t.meta['state'][:-1].ravel() for t in day_herds])
    assert 0.03 <= np.median(v[state == GRAZING]) <= 0.15
    assert 0.6 <= np.median(v[state == WALKING]) <= 1.2
    assert np.percentile(v[state == RESTING], 90) < 0.05


def test_cohesion_and_spacing(hour_herd, day_herds, l_paddock_herd):
    for traj in [hour_herd, *day_herds, l_paddock_herd]:
        d = pair_distances(traj)
        assert 3.0 < np.median(d) < 100.0
        assert d.min() > 1.0


def test_daily_behaviour_budget(day_herds):
    state = np.concatenate([t.meta['state'].ravel() for t in day_herds])
    grazing, walking, resting = ((state == s).mean() for s in (GRAZING, WALKING, RESTING))
    assert 0.38 <= grazing <= 0.62
    assert 0.25 <= resting <= 0.50
    assert 0.03 <= walking <= 0.13


def test_time_of_day_pattern_water_and_shade(day_herds):
    for traj in day_herds:
        paddock = traj.meta['paddock']
        hour = solar_hour(traj.times, paddock.datum[1])
        state = traj.meta['state']
        dawn_dusk = ((hour > 6) & (hour < 9)) | ((hour > 16) & (hour < 20))
        midday = (hour > 11) & (hour < 16)
        assert (state[dawn_dusk] == GRAZING).mean() > (state[midday] == GRAZING).mean() + 0.2
        # every cow visits the water trough at least once a day
        to_water = np.linalg.norm(traj.positions - paddock.water[0], axis=-1)
        assert (to_water.min(axis=0) < 10.0).all()
        # midday rest is mostly in the shade, rest at other times mostly not
        to_shade = np.linalg.norm(traj.positions[:, :, None, :] - paddock.shade, axis=-1).min(-1)
        rest_mid = (state == RESTING) & midday[:, None]
        rest_other = (state == RESTING) & ~midday[:, None]
        assert (to_shade[rest_mid] < 15.0).mean() > 0.6
        assert (to_shade[rest_mid] < 15.0).mean() > (to_shade[rest_other] < 15.0).mean() + 0.3


def test_deterministic_for_a_seed():
    a = simulate_cow_herd(n_cows=4, duration_s=600.0, seed=7)
    b = simulate_cow_herd(n_cows=4, duration_s=600.0, seed=7)
    c = simulate_cow_herd(n_cows=4, duration_s=600.0, seed=8)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.meta['state'], b.meta['state'])
    assert not np.allclose(a.positions, c.positions)


def test_custom_ids_single_cow_and_start_time():
    traj = simulate_cow_herd(duration_s=120.0, dt=2.0, agents=['bessie', 'daisy'],
                             start_time=1_700_000_000.0)
    assert traj.agents == ['bessie', 'daisy'] and traj.positions.shape == (60, 2, 2)
    assert traj.times[0] == 1_700_000_000.0 and np.allclose(np.diff(traj.times), 2.0)
    one = simulate_cow_herd(n_cows=1, duration_s=300.0, seed=1)
    assert one.positions.shape == (300, 1, 2) and np.isfinite(one.positions).all()


@pytest.mark.parametrize('kwargs', [
    dict(n_cows=0), dict(dt=0.0), dict(dt=float('nan')), dict(duration_s=1.0),
    dict(agents=['a', 'a']),
    dict(paddock='water outside'), dict(paddock='tiny'),
])
def test_bad_input_is_one_clear_error(kwargs):
    if kwargs.get('paddock') == 'water outside':
        kwargs['paddock'] = None
        with pytest.raises(HerdInputError, match='water'):
            Paddock(water=[[500.0, 0.0]])
        return
    if kwargs.get('paddock') == 'tiny':
        kwargs['paddock'] = Paddock(fence=[[0, 0], [12, 0], [12, 12], [0, 12]],
                                    water=[[6, 6]], shade=[])
        kwargs['n_cows'] = 10
    with pytest.raises(HerdInputError):
        simulate_cow_herd(**{'duration_s': 60.0, **kwargs})
