"""Free-run fidelity (issue 30): the statistics by hand, and a law that is the truth without
noise reproduces its data exactly when run freely."""
import numpy as np
import pytest

from herd_ros.simulation.free_run import (format_free_run, free_run_fidelity, observed_like,
                                          shape_and_pace)
from herd_ros.simulation.herd_simulator import simulate
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model
from herd_ros.trajectory import HerdTrajectory


def test_shape_and_pace_by_hand():
    T = 4000
    p = np.zeros((T, 2, 2))
    p[:, 1, 0] = np.where(np.arange(T) % 2 == 0, 10.0, 20.0)   # b hops 10 m <-> 20 m
    s = shape_and_pace(p, 1.0)
    assert s['distance'] == pytest.approx([15.0, 15.0])
    assert s['spread'] == pytest.approx([5.0, 5.0])
    assert s['mean_speed'] == pytest.approx([0.0, 10.0]) and s['std_speed'] == pytest.approx(
        [0.0, 0.0])
    assert s['pace'] == pytest.approx([0.0, 0.0])          # back where it was every 600 s
    q = np.zeros((T, 2, 2))
    q[:, 1, 0] = 100.0 + 0.05 * np.arange(T)               # walks away at 5 cm/s
    assert shape_and_pace(q, 1.0)['pace'][1] == pytest.approx(0.05)
    q[100:200, 0] = np.nan                                 # a missing stretch is skipped
    assert np.isfinite(shape_and_pace(q, 1.0)['distance']).all()
    # a clock coarser than the 10-minute window (hourly fixes): the pace per step
    h = np.zeros((40, 2, 2))
    h[:, 1, 0] = 3600.0 * 0.02 * np.arange(40)             # 2 cm/s, one fix an hour
    assert shape_and_pace(h, 3600.0)['pace'][1] == pytest.approx(0.02)


def test_the_noise_free_truth_reproduces_its_data():
    truth = make_truth_model(3, seed=1, noise_std=0.0)
    run = simulate(truth, 800, initial_positions(truth, seed=1, spread=25), seed=0)
    result = free_run_fidelity(truth, run, seeds=2)
    for stat, row in result['herd'].items():
        assert row['relative'] == pytest.approx(0.0, abs=1e-9), stat
        assert row['min'] == pytest.approx(row['max'])
    assert set(result['per_agent']) == set(truth.agents)
    assert 'free run from the held-out start (800 steps, 2 noise seeds' in format_free_run(
        result, per_agent=True)


def test_a_noisy_law_spreads_its_runs():
    truth = make_truth_model(3, seed=1)
    run = simulate(truth, 800, initial_positions(truth, seed=1, spread=25), seed=0)
    r = free_run_fidelity(truth, HerdTrajectory(run.times, run.agents, run.positions),
                          seeds=3)['herd']['mean_speed']
    assert r['min'] < r['max'] and r['min'] <= r['median'] <= r['max']


def test_runs_are_seen_where_the_data_are():
    """A collar silent for a stretch changes who "the others" are; the noise-free truth, run
    freely and seen like its data, still reproduces them exactly — seen whole, it would not."""
    truth = make_truth_model(3, seed=1, noise_std=0.0)
    run = simulate(truth, 800, initial_positions(truth, seed=1, spread=25), seed=0)
    p = run.positions.copy()
    p[200:700, 2] = np.nan                 # the third collar silent for 500 steps
    gappy = HerdTrajectory(run.times, run.agents, p)
    result = free_run_fidelity(truth, gappy, seeds=2)
    for stat, row in result['herd'].items():
        assert row['relative'] == pytest.approx(0.0, abs=1e-9), stat
    whole = shape_and_pace(run.positions, truth.dt)      # the run, seen whole
    seen = shape_and_pace(p, truth.dt)
    assert not np.allclose(whole['spread'], seen['spread'], rtol=0.05)


def test_observed_like_aligns_a_run_that_starts_late():
    times = np.arange(6.0)
    data = np.zeros((6, 2, 2))
    data[0, 0] = np.nan                    # no complete snapshot at 0: the run starts at 1
    data[3, 1] = np.nan
    sim = HerdTrajectory(times[1:], ['a', 'b'], np.ones((5, 2, 2)))
    seen, span = observed_like(sim, data, times)
    assert seen.shape == span.shape == (5, 2, 2)
    assert np.isnan(seen[2, 1]).all() and np.isfinite(np.delete(seen, 2, axis=0)).all()
    assert np.isfinite(seen[:, 0]).all()


@pytest.mark.parametrize('regimes', [False, True])
def test_runs_simulated_together_are_each_the_run_alone(monkeypatch, regimes):
    """simulate_from_each (one step of the law for every run) gives, run by run, exactly
    what simulate_from gives alone: runs of different lengths, an animal that starts late,
    herd places, Gaussian or switching noise, and batches split by the memory bound."""
    import dataclasses

    from herd_ros.errors import HerdInputError
    from herd_ros.model.herd_place import with_herd_place
    from herd_ros.simulation import herd_simulator
    from herd_ros.simulation.herd_simulator import simulate_from, simulate_from_each
    truth = make_truth_model(3, seed=1)
    data = simulate(truth, 400, initial_positions(truth, seed=1, spread=25), seed=0)
    model = with_herd_place(truth, data.positions)
    assert model.meta.get('herd_place') is not None
    if regimes:                     # a resting and a moving regime per animal
        cov = np.stack([np.stack([0.01 * q, 4.0 * q]) for q in model.noise_cov])
        trans = np.tile([[0.95, 0.05], [0.1, 0.9]], (3, 1, 1))
        model = dataclasses.replace(model, meta={**model.meta, 'noise_regimes': (cov, trans)})
    p = data.positions.copy()
    p[:5, 1] = np.nan                                   # the second animal starts late
    runs = [HerdTrajectory(data.times[k:], data.agents, p[k:]) for k in (0, 30, 150, 0)]
    seeds = [3, 4, 5, 6]
    for bound in (10 ** 6, 2_500):                      # one batch; then two runs each
        monkeypatch.setattr(herd_simulator, 'BATCH_POSITIONS', bound)
        together = simulate_from_each(model, runs, seeds)
        for run, seed, sim in zip(runs, seeds, together):
            alone = simulate_from(model, run, seed=seed)
            assert np.array_equal(sim.times, alone.times)
            assert np.array_equal(sim.positions, alone.positions)
    assert not np.array_equal(together[0].positions, together[3].positions)  # seeds differ
    with pytest.raises(HerdInputError, match='4 runs need as many seeds, got 2'):
        simulate_from_each(model, runs, [1, 2])
