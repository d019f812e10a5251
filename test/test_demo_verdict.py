"""The demo's verdict (issue 30): each robot against its animal — where it started and
whether every statistic is within the bar."""
import numpy as np
import pytest

from herd_ros.report.demo_report import PASS_BAR, seen_like_animals, verdict
from herd_ros.trajectory import HerdTrajectory


def test_start_offset_and_pass_by_hand():
    t = np.arange(5.0)
    cows = HerdTrajectory(t, ['c1', 'c2'], np.zeros((5, 2, 2)))
    cows.positions[:, 1] = (10.0, 0.0)
    cows.positions[0, 0] = np.nan                  # c1's first herd pose is at t = 1
    cows.positions[1:, 0] = (3.0, 4.0)
    robots = HerdTrajectory(t, ['r1', 'r2'], np.zeros((5, 2, 2)))
    robots.positions[:, 1] = (10.0, 1.0)
    rel = {'r1': {'mean_distance': 0.1, 'mean_speed': PASS_BAR},
           'r2': {'mean_distance': 0.1, 'mean_speed': PASS_BAR + 0.01}}
    v = verdict(cows, robots, ['c1', 'c2'], rel, {'mean_distance': 0.2})
    assert v['robots']['r1']['start_offset_m'] == 5.0      # (0, 0) vs (3, 4)
    assert v['robots']['r2']['start_offset_m'] == 1.0
    assert v['robots']['r1']['pass'] and not v['robots']['r2']['pass']
    assert v['herd_pass'] and not verdict(cows, robots, ['c1', 'c2'], rel,
                                          {'mean_distance': 0.31})['herd_pass']


def test_the_start_offset_is_taken_when_the_robot_starts():
    # a robot scored from t = 3 (its law took over then) is measured against where its
    # animal was at t = 3, not at the animal's first herd pose
    t = np.arange(6.0)
    cows = HerdTrajectory(t, ['c1'], np.zeros((6, 1, 2)))
    cows.positions[:, 0, 0] = 2.0 * t                        # walks east, 2 m per tick
    robots = HerdTrajectory(t[3:], ['r1'], np.zeros((3, 1, 2)))
    robots.positions[:, 0] = (6.0, 1.5)                      # the animal is at (6, 0) at t = 3
    v = verdict(cows, robots, ['c1'], {}, {})
    assert v['robots']['r1']['start_offset_m'] == 1.5
    # the robot's first sample between two herd ticks: the animal's latest pose before it
    late = HerdTrajectory(np.array([3.5]), ['r1'], np.array([[[6.0, 0.0]]]))
    assert verdict(cows, late, ['c1'], {}, {})['robots']['r1']['start_offset_m'] == 0.0


def test_published_skill_on_a_finer_herd_clock_scores_the_same_model_steps():
    # the herd every 30 s, the model's step 120 s: the skill looks a model step back on the
    # fine clock and equals the skill on the herd taken every 120 s; by hand, a prediction
    # off by 3 m at every scored tick gives a model RMS of 3 m
    import numpy as np

    from herd_ros.simulation.prediction import published_prediction_skill
    from herd_ros.trajectory import HerdTrajectory
    rng = np.random.default_rng(0)
    fine_t = 30.0 * np.arange(400)
    fine_p = np.cumsum(rng.normal(0, 2, (400, 2, 2)), axis=0)
    coarse = slice(0, None, 4)
    pred_t = fine_t[coarse][2:]
    pred_p = fine_p[coarse][2:] + np.array([3.0, 0.0])
    preds = HerdTrajectory(pred_t, ['a', 'b'], pred_p)
    fine = published_prediction_skill(HerdTrajectory(fine_t, ['a', 'b'], fine_p), preds,
                                      120.0, clock=30.0)
    plain = published_prediction_skill(
        HerdTrajectory(fine_t[coarse], ['a', 'b'], fine_p[coarse]), preds, 120.0)
    assert fine['model'] == pytest.approx(3.0) and fine['samples'] == plain['samples'] > 0
    for m in ('model', 'constant_velocity', 'stay_put', 'damping_only'):
        assert fine[m] == pytest.approx(plain[m]), m


def test_robots_are_seen_like_their_animals():
    cows = HerdTrajectory(np.array([0.0, 10.0, 20.0, 30.0]), ['a', 'b'], np.zeros((4, 2, 2)))
    cows.positions[2, 0] = np.nan                     # a's collar silent at 20 s
    robots = HerdTrajectory(np.array([-5.0, 5.0, 15.0, 25.0, 35.0, 45.0]), ['r1', 'r2'],
                            np.ones((6, 2, 2)))
    seen = seen_like_animals(cows, robots, ['a', 'b'])
    r1, r2 = np.isfinite(seen.positions[:, 0, 0]), np.isfinite(seen.positions[:, 1, 0])
    # before the first snapshot, and more than a clock step after the last: nobody
    assert r1.tolist() == [False, True, True, False, True, False]
    assert r2.tolist() == [False, True, True, True, True, False]
    assert np.isfinite(robots.positions).all()        # the input is left alone


def test_robots_are_matched_to_herd_ticks_by_their_stamps():
    """Fleet poses arrive out of order and in bursts at high replay rates: each herd tick
    takes the last snapshot stamped at or before it, none before the first or when the
    fleet had not got there (more than two fleet steps since its last snapshot)."""
    from herd_ros.cli.live_demo import robots_at
    stamps = [10.0, 0.0, 20.0, 30.0]                 # the 0 s snapshot arrived second
    xy = np.array([[[1.0, 1.0]], [[0.0, 0.0]], [[2.0, 2.0]], [[3.0, 3.0]]])
    at = robots_at([-1.0, 0.0, 5.0, 10.0, 25.0, 30.0, 45.0, 51.0], stamps, xy)[:, 0, 0]
    assert np.isnan(at[0]) and np.isnan(at[-1])
    assert at[1:-1].tolist() == [0.0, 0.0, 1.0, 2.0, 3.0, 3.0]
    assert np.isnan(robots_at([1.0, 2.0], [], np.zeros((0, 1, 2)))).all()
    # between snapshots (an animal's fix stamps), linearly; past the last one, held
    at = robots_at([5.0, 12.5, 25.0, 45.0], stamps, xy, interpolate=True)[:, 0, 0]
    assert at.tolist() == [0.5, 1.25, 2.5, 3.0]


def test_robots_are_seen_at_their_animals_fixes():
    """Robot 0's animal reports at 10 s and 35 s: at tick 0 the robot is nowhere (no fix
    yet), at ticks 10, 20 and 30 where it was at 10 s, at tick 40 where it was at 35 s;
    robot 1's animal never reports."""
    from herd_ros.report.demo_report import seen_at_fixes
    times = np.array([0.0, 10.0, 20.0, 30.0, 40.0])
    held = seen_at_fixes(times, [np.array([10.0, 35.0]), np.array([])],
                         [np.array([[1.0, 2.0], [5.0, 6.0]]), np.zeros((0, 2))])
    assert held.shape == (5, 2, 2)
    assert np.isnan(held[0, 0]).all()
    np.testing.assert_array_equal(held[1:4, 0], [[1.0, 2.0]] * 3)
    np.testing.assert_array_equal(held[4, 0], [5.0, 6.0])
    assert np.isnan(held[:, 1]).all()


def test_a_robot_that_retraces_its_animal_passes_when_both_are_seen_at_the_fixes(tmp_path):
    """Two animals walk known zigzags, fixed every 30-150 s; their tracks on a 10 s clock
    move between fixes (here: straight from fix to fix, as a collar's fitted velocity
    carries a track on), and two robots retrace the animals exactly. Seen at the animals'
    fixes, animals and robots are the same samples: every statistic agrees to rounding,
    and every robot passes. The robots seen at the fixes against the herd poses at the
    ticks (the comparison before) differ in the spread of speed: a track that moves
    between fixes spreads each fix's step over several ticks."""
    from herd_ros.report.demo_report import seen_at_fixes, write_demo_report
    times = np.arange(0.0, 3600.0, 10.0)
    rng = np.random.default_rng(4)
    fixes = [np.cumsum(rng.uniform(30.0, 150.0, 40)) for _ in range(2)]
    fixes = [f[f < times[-1]] for f in fixes]

    def path(t, k):                                   # the animals' true positions
        return np.stack([0.02 * t + 5.0 * np.sin(t / (200.0 + 50 * k)) + 20.0 * k,
                         3.0 * np.cos(t / 150.0) + 10.0 * k], axis=-1)

    fix_xy = [path(f, k) for k, f in enumerate(fixes)]
    track = np.full((len(times), 2, 2), np.nan)       # straight from fix to fix, then held
    for k, (f, xy) in enumerate(zip(fixes, fix_xy)):
        on = times >= f[0]
        for d in range(2):
            track[on, k, d] = np.interp(times[on], f, xy[:, d])
    cows = HerdTrajectory(times, ['a', 'b'], track)
    robots_xy = np.stack([path(times, 0), path(times, 1)], axis=1)
    robots = HerdTrajectory(times, ['r1', 'r2'], robots_xy)
    at_fixes = HerdTrajectory(times, ['r1', 'r2'], seen_at_fixes(times, fixes, fix_xy))
    cows_at_fixes = HerdTrajectory(times, ['a', 'b'], np.where(
        np.isfinite(track), seen_at_fixes(times, fixes, fix_xy), np.nan))
    s = write_demo_report(tmp_path, cows, robots, ['a', 'b'], [], [],
                          robots_at_fixes=at_fixes, cows_at_fixes=cows_at_fixes)
    assert max(s['herd_relative_difference'].values()) < 1e-9
    assert all(e['pass'] for e in s['verdict']['robots'].values()) and s['verdict']['herd_pass']
    before = write_demo_report(tmp_path / 'before', cows, robots, ['a', 'b'], [], [],
                               robots_at_fixes=at_fixes)
    assert before['herd_relative_difference']['std_speed'] > 0.5
    assert s['cows_continuous'] == before['cows']
