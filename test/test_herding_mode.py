"""The controller's herding mode with the model herder, on a real node in process: it herds
with Strömbom's shepherd while it learns, then plans with the learned law; a model herder
that fails hands back to Strömbom's shepherd with one error, and the mode keeps running."""
import numpy as np
import rclpy
from geometry_msgs.msg import Pose, PoseArray
from rclpy.node import Node

from herd_ros.control.fleet_observation import FleetObservation
from herd_ros.nodes.herding_mode import HerdingPolicy
from herd_ros.params.controller import HERDING


def observation(robots_xy, t):
    n = len(robots_xy)
    return FleetObservation([f'herder_{k + 1}' for k in range(n)], np.ones(n, bool),
                            np.asarray(robots_xy, float), np.zeros(n), np.zeros((n, 2)),
                            np.ones(n, bool), np.zeros((n, 2)), 0.2, t)


def herd_message(xy):
    msg = PoseArray()
    for x, y in xy:
        p = Pose()
        p.position.x, p.position.y = float(x), float(y)
        msg.poses.append(p)
    return msg


def test_the_model_herder_learns_then_plans_and_falls_back(ros_env):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    node = Node('herding_mode_test', context=context)
    try:
        params = {k: v.default for k, v in HERDING.items()} | {'herder': 'model'}
        policy = HerdingPolicy(node, params)
        rng = np.random.default_rng(0)
        herd = 100.0 + rng.uniform(0, 20, (6, 2))
        robot = [[145.0, 145.0]]
        policy.on_poses(herd_message(herd))
        v = policy.command(observation(robot, 0.0))
        assert np.isfinite(v).all() and policy.phase in ('collecting', 'driving')
        assert 'learns the response' in policy.status
        policy._learning['thread'].join(timeout=120)
        for step in range(1, 12):                 # one herd snapshot per 1 s step
            herd = herd - 0.5
            policy.on_poses(herd_message(herd))
            v = policy.command(observation(robot, float(step)))
        assert policy.phase == 'planning' and np.isfinite(v).all()
        assert policy._model_state['online'].rows[0] > 0        # refitted from what it saw

        def broken(*args):
            raise ValueError('a planner bug')
        policy.model = broken
        policy.on_poses(herd_message(herd - 0.5))
        v = policy.command(observation(robot, 12.0))
        assert np.isfinite(v).all() and policy.phase in ('collecting', 'driving')
        policy.on_poses(herd_message(herd - 1.0))
        v = policy.command(observation(robot, 13.0))
        assert np.isfinite(v).all() and policy.phase in ('collecting', 'driving')
        assert 'learns' not in policy.status
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_with_model_warmup_hold_the_robots_wait_for_the_model_herder(ros_env):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    node = Node('herding_hold_test', context=context)
    try:
        params = {k: v.default for k, v in HERDING.items()} | {'herder': 'model',
                                                                'model_warmup': 'hold'}
        policy = HerdingPolicy(node, params)
        herd = 100.0 + np.random.default_rng(1).uniform(0, 20, (6, 2))
        robot = [[145.0, 145.0]]
        policy.on_poses(herd_message(herd))
        v = policy.command(observation(robot, 0.0))
        assert policy.phase == 'holding' and (v == 0.0).all()
        assert 'holding still while the model herder learns' in policy.status
        policy._learning['thread'].join(timeout=120)
        policy.on_poses(herd_message(herd - 0.5))
        v = policy.command(observation(robot, 1.0))
        assert policy.phase == 'planning' and np.isfinite(v).all() and (v != 0.0).any()
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
