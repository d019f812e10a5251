"""The demo's verdict (issue 30): each robot against its animal — where it started and
whether every statistic is within the bar."""
import numpy as np

from herd_ros.report.demo_report import PASS_BAR, verdict
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
