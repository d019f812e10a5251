"""The tracking measure of issue 25 (:mod:`herd_ros.ingest.tracking_score`), by hand."""
import numpy as np
import pandas as pd

from herd_ros.ingest.herd_clock import StateTimeline
from herd_ros.ingest.tracking_score import (collar_track_distances,
                                            format_ingest_tracking_score,
                                            ingest_tracking_score, next_fix_distances,
                                            paired, summarise)


def fixes():
    return pd.DataFrame({'time': [0.0, 10.0, 20.0, 20.0], 'agent': ['a'] * 4,
                         'x': [0.0, 10.0, 20.0, 21.0], 'y': [0.0, 0.0, 0.0, 0.0]})


def test_the_track_and_the_raw_fix_are_scored_by_hand():
    # the clock's poses at 5 s and 15 s; the fix at 10 s: track (5, 0), raw (0, 0);
    # at 20 s (twice: a duplicated stamp is not "before" its twin) track (15, 0), raw (10, 0)
    d_t, d_r = next_fix_distances(fixes(), np.array([5.0, 15.0]),
                                  np.array([[[5.0, 0.0]], [[15.0, 0.0]]]), ['a'])
    np.testing.assert_allclose(d_t, [5.0, 5.0, 6.0])
    np.testing.assert_allclose(d_r, [10.0, 10.0, 11.0])
    # a mask leaves fixes out of the score, never out of the predecessors
    d_t, d_r = next_fix_distances(fixes(), np.array([5.0, 15.0]),
                                  np.array([[[5.0, 0.0]], [[15.0, 0.0]]]), ['a'],
                                  targets=np.array([True, False, True, True]))
    np.testing.assert_allclose(d_r, [10.0, 11.0])
    s = summarise([3.0, 4.0, 200.0])
    assert s['median'] == 4.0 and abs(s['beyond_100m'] - 1 / 3) < 1e-12


def test_a_collar_track_predicts_its_last_state_to_the_fix():
    # states at 0 s and 10 s moving east at 1 m/s, constant velocity without noise: just
    # before 20 s the track says (20, 0)
    x = np.array([[0.0, 0.0, 1.0, 0.0], [10.0, 0.0, 1.0, 0.0]])
    tl = StateTimeline(np.array([0.0, 10.0]), x, np.zeros((2, 4, 4)), 1e-9, 1e6)
    d_t, d_r = collar_track_distances(fixes(), {'a': tl})
    np.testing.assert_allclose(d_t, [0.0, 0.0, 1.0], atol=1e-5)
    np.testing.assert_allclose(d_r, [10.0, 10.0, 11.0])


def test_the_paired_comparison_counts_who_is_closer_by_hand():
    # closer, farther, closer, a tie within 1 mm, a NaN pair left out
    p = paired([1.0, 3.0, 0.5, 2.0005, np.nan], [2.0, 2.0, 1.0, 2.0, 1.0])
    assert p['n'] == 4 and p['ties'] == 0.25
    assert abs(p['closer'] - 2 / 3) < 1e-12
    lo, hi = p['closer_ci']
    assert lo < 2 / 3 < hi and lo > 0.0 and hi < 1.0
    # median of (−1, 1, −0.5, 0.0005)
    assert abs(p['median_difference'] - (-0.5 + 0.0005) / 2) < 1e-12


def test_ingest_scores_every_fix_and_the_accepted_ones_by_hand():
    # a collar moving east at 1 m/s, its states after the fixes at 0, 10 and 20 s; the fix
    # at 30 s, 20 m ahead of the animal, was rejected (no state at 30 s)
    x = np.array([[0.0, 0.0, 1.0, 0.0], [10.0, 0.0, 1.0, 0.0], [20.0, 0.0, 1.0, 0.0]])
    tl = StateTimeline(np.array([0.0, 10.0, 20.0]), x, np.zeros((3, 4, 4)), 1e-9, 1e6)
    raw = {'a': (np.array([0.0, 10.0, 20.0, 30.0]),
                 np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [50.0, 0.0]]))}
    score = ingest_tracking_score(raw, {'a': tl})
    # every fix after the first: the track says 10, 20, 30 m; the last raw fix 0, 10, 20
    every = score['every']
    assert every['track']['n'] == 3 and every['last_raw_fix']['n'] == 3
    assert abs(every['track']['median'] - 0.0) < 1e-4
    assert abs(every['track']['rms'] - np.sqrt(20.0 ** 2 / 3)) < 1e-4
    assert abs(every['last_raw_fix']['median'] - 10.0) < 1e-9
    assert abs(every['last_raw_fix']['rms'] - np.sqrt((100 + 100 + 900) / 3)) < 1e-9
    # the accepted fixes: 10 and 20 s
    acc = score['accepted']
    assert acc['track']['n'] == 2 and acc['track']['p99'] < 1e-4
    assert abs(acc['last_raw_fix']['median'] - 10.0) < 1e-9
    text = format_ingest_tracking_score(score)
    assert every['eligible'] == 3 and acc['eligible'] == 2
    assert 'every valid fix' in text and '(n 3 of 3)' in text and '(n 2 of 2)' in text
    assert 'last raw fix' in text
    # the track file: a clock every 5 s at the animal's place, NaN at 25 s (stale); each
    # fix against the clock's last finite pose before it: 5 s, 15 s, 20 s -> 5, 5, 30 m
    ticks = np.arange(0.0, 30.0, 5.0)
    poses = np.column_stack([ticks, np.zeros(6)])[:, None, :].copy()
    poses[5] = np.nan
    file = ingest_tracking_score(raw, {'a': tl}, clock=(ticks, poses, ['a']))['file']
    assert file['track']['n'] == 3 and file['eligible'] == 3
    assert abs(file['track']['median'] - 5.0) < 1e-9
    assert abs(file['track']['rms'] - np.sqrt((25 + 25 + 900) / 3)) < 1e-9
    assert abs(file['last_raw_fix']['rms'] - np.sqrt((100 + 100 + 900) / 3)) < 1e-9
    assert 'track file' in format_ingest_tracking_score(
        ingest_tracking_score(raw, {'a': tl}, clock=(ticks, poses, ['a'])))
    assert 'file' not in score
    # above max_scored fixes, every k-th fix of each collar (k = 2 here: 0 and 20 s)
    thin = ingest_tracking_score(raw, {'a': tl}, max_scored=2)['every']
    assert thin['stride'] == 2 and thin['eligible'] == 1 and thin['track']['n'] == 1
    assert abs(thin['last_raw_fix']['median'] - 10.0) < 1e-9


def test_the_longest_run_of_fixes_the_track_did_not_take_by_hand():
    from herd_ros.ingest.pipeline import format_refusal_runs, refusal_runs
    # fixes at 0..9 s; the track took 0, 1, 5 and 9 (its states): runs 2-4 (3 fixes) and
    # 6-8 (3 fixes, the later one not longer: the first is kept); a collar that took all
    x = np.zeros((4, 4))
    took = StateTimeline(np.array([0.0, 1.0, 5.0, 9.0]), x, np.zeros((4, 4, 4)), 1e-9, 1e6)
    every = StateTimeline(np.arange(3.0), x[:3], np.zeros((3, 4, 4)), 1e-9, 1e6)
    raw = {'a': (np.arange(10.0), np.zeros((10, 2))), 'b': (np.arange(3.0), np.zeros((3, 2)))}
    runs = refusal_runs(raw, {'a': took, 'b': every}, t0=-100.0)
    assert runs['a'] == (3, 102.0, 104.0)
    assert runs['b'][0] == 0 and np.isnan(runs['b'][1])
    # said only where a run outlasts stale_after (2 s here, not 3)
    assert 'a 3 fixes from 0.03 h for 0 min' in format_refusal_runs(runs, 1.5)
    assert format_refusal_runs(runs, 2.0) == ''
