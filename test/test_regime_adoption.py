"""The estimator adopts a noise-regime refit at a set update (``regime_adopt_after`` after
it started), in data time: whether the worker's fit takes a millisecond or half a second,
the regimes are published at the same snapshot, so a bag replayed at any rate gives the
same regimes at the same tick (adopted when the worker finished, the robots of a replay
drew their noise from another tick from run to run: doc/real_herds.md, the calves' demo).

A real estimator node in-process, fed real PoseArray messages through its callback; the
worker's fit is slowed by wrapping the numeric function it runs.
"""
import os
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from geometry_msgs.msg import Pose, PoseArray  # noqa: E402

from herd_ros.nodes.ros_common import seconds_to_stamp  # noqa: E402

AGENTS = ['a', 'b']
REFIT_EVERY, ADOPT_AFTER = 130, 7


def snapshots(n, seed=0):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0.0, 0.3, (n, len(AGENTS), 2)), axis=0) + [[0.0, 0.0],
                                                                            [5.0, 0.0]]


def adoption_updates(ros_env, tmp_path, delay):
    """The updates at which the node published noise regimes, its fit slowed by ``delay``
    seconds."""
    import herd_ros.estimation.online_regimes as regimes
    from herd_ros.nodes.estimator import Estimator

    fit = regimes.fit_residuals

    def slow(residuals):
        time.sleep(delay)
        return fit(residuals)
    os.environ['ROS_DOMAIN_ID'] = ros_env['ROS_DOMAIN_ID']
    rclpy.init(args=[
        '--ros-args', '-p', f'agents:={AGENTS}', '-p', 'dt:=1.0', '-p', 'regime_window:=120',
        '-p', f'regime_refit_every:={REFIT_EVERY}', '-p', f'regime_adopt_after:={ADOPT_AFTER}',
        '-p', f'model_out:={tmp_path / "m.yaml"}', '-p', "checkpoint_path:=''"])
    regimes.fit_residuals = slow
    adopted = []
    try:
        node = Estimator()
        publish = node.regimes_pub.publish
        node.regimes_pub.publish = lambda msg: (adopted.append(node.counts['updates']),
                                                publish(msg))
        for k, xy in enumerate(snapshots(4 * REFIT_EVERY)):
            msg = PoseArray()
            msg.header.stamp = seconds_to_stamp(1000.0 + k)
            msg.poses = [Pose() for _ in AGENTS]
            for p, (x, y) in zip(msg.poses, xy):
                p.position.x, p.position.y = float(x), float(y)
            node.on_poses(msg)
        node.destroy_node()
    finally:
        regimes.fit_residuals = fit
        rclpy.shutdown()
    return adopted


def test_regimes_are_adopted_at_the_same_update_however_long_the_fit(ros_env, tmp_path):
    fast = adoption_updates(ros_env, tmp_path, 0.0)
    slow = adoption_updates(ros_env, tmp_path, 0.3)
    assert fast == slow
    # each at its refit's update + regime_adopt_after (the first refit with a full window)
    assert len(fast) >= 2 and all((u - ADOPT_AFTER) % REFIT_EVERY == 0 for u in fast), fast
