"""fleet_sim and controller as separate processes (installed console scripts, loopback DDS).

The test process listens (and for the live-model test, talks) with its own rclpy context on
the subprocesses' domain. Safety checks: commanded speed ≤ max_speed, robots stay inside the
fence (which only the controller knows: the simulator has none, so nothing else holds them),
stale odometry -> zero commands, stale commands -> robots stop, robots not owned are never
commanded.
"""
import math
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String

from herd_ros.model.model_file import save_model
from herd_ros.model.model_structure import ModelStructure
from herd_ros.synthesis.known_truth import make_truth_model
from ros_harness import TestListener, start, stop

CONFIG = Path(__file__).resolve().parents[1] / 'config'
FENCE = [-4.0, -4.0, 4.0, -4.0, 4.0, 4.0, -4.0, 4.0]
POSES = [-1.0, 0.0, 0.0, 1.0, 0.0, 1.57, 0.0, 1.5, -1.57]


def flag(name, values):
    return f'{name}:=[{", ".join(str(v) for v in values)}]'


@pytest.fixture
def graph(ros_env, console_script, tmp_path):
    """Start processes with ``graph.start(name, *ros_args)``; all are stopped afterwards."""
    procs = []
    model_path = tmp_path / 'model.yaml'
    save_model(make_truth_model(3, seed=1), model_path)

    class Graph:
        env = ros_env
        model = model_path

        def start(self, name, *ros_args):
            proc = start([console_script(name), '--ros-args', *ros_args], ros_env,
                         tmp_path / f'{name}.log')
            procs.append(proc)
            return proc

        def output(self, name):
            return (tmp_path / f'{name}.log').read_text()

    listener = TestListener(ros_env, 'fleet_test_listener')
    try:
        yield Graph(), listener
    finally:
        for proc in procs:
            stop(proc)
        listener.close()


def odom_xy(msg):
    return msg.pose.pose.position.x, msg.pose.pose.position.y


def odom_speed(msg):
    return math.hypot(msg.twist.twist.linear.x, msg.twist.twist.linear.y)


def stamp(msg):
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def sim_args(kinematics='holonomic'):
    return ['-p', 'robots:=[r1, r2, r3]', '-p', flag('initial_poses', POSES),
            '-p', f'kinematics:={kinematics}', '-p', 'max_speed:=2.0', '-p', 'max_accel:=4.0',
            '-p', 'rate_hz:=20.0', '-p', 'cmd_timeout_s:=1.0']


def controller_args(graph, kinematics='holonomic'):
    return ['--params-file', str(graph.model), '-p', 'robots:=[r1, r2]',
            '-p', 'other_robots:=[r3]', '-p', f'kinematics:={kinematics}',
            '-p', 'max_speed:=0.8', '-p', flag('fence', FENCE), '-p', 'fence_margin:=0.3',
            '-p', 'rate_hz:=10.0', '-p', 'odom_timeout_s:=0.5']


def test_robots_move_within_speed_and_fence_and_unowned_robots_are_left_alone(graph):
    g, ear = graph
    cmds = {r: ear.record(Twist, f'/fleet/{r}/cmd_vel') for r in ('r1', 'r2', 'r3')}
    odom = {r: ear.record(Odometry, f'/fleet/{r}/odom') for r in ('r1', 'r2', 'r3')}
    g.start('fleet_sim', *sim_args())
    g.start('controller', *controller_args(g))

    def near_fence():
        xy = [odom_xy(m) for r in ('r1', 'r2') for _, m in odom[r][-1:]]
        return len(xy) == 2 and max(max(abs(x), abs(y)) for x, y in xy) > 3.4
    assert ear.spin(25.0, until=near_fence), 'robots never reached the fence'
    ear.spin(3.0)                                     # keep pushing against it a while

    for r in ('r1', 'r2'):
        speeds = [math.hypot(m.linear.x, m.linear.y) for _, m in cmds[r]]
        assert len(speeds) > 20 and max(speeds) <= 0.8 + 1e-9
        xy = np.array([odom_xy(m) for _, m in odom[r]])
        assert np.abs(xy).max() < 4.0, f'{r} left the fence'
        assert np.hypot(*(xy[-1] - xy[0])) > 1.0, f'{r} did not move'
    assert cmds['r3'] == [], 'the controller commanded a robot it does not own'
    r3 = np.array([odom_xy(m) for _, m in odom['r3']])
    np.testing.assert_allclose(r3, r3[:1].repeat(len(r3), 0), atol=1e-9)


def test_stale_commands_stop_unicycles_within_cmd_timeout(graph):
    g, ear = graph
    odom = {r: ear.record(Odometry, f'/fleet/{r}/odom') for r in ('r1', 'r2')}
    cmds = ear.record(Twist, '/fleet/r1/cmd_vel')
    g.start('fleet_sim', *sim_args('unicycle'))
    ctl = g.start('controller', *controller_args(g, 'unicycle'))

    def moving():
        return any(odom[r] and odom_speed(odom[r][-1][1]) > 0.1 for r in odom)
    assert ear.spin(20.0, until=moving), 'robots never moved'
    ear.spin(1.0)
    assert all(abs(m.linear.x) <= 0.8 + 1e-9 and m.linear.y == 0.0 for _, m in cmds)
    stop(ctl)
    t_exit = time.time()
    ear.spin(2.0)
    after = [m for r in odom for t, m in odom[r] if stamp(m) > t_exit + 1.0 + 0.15]
    assert len(after) > 10
    assert max(odom_speed(m) for m in after) == 0.0


def test_a_command_takes_effect_on_arrival_and_poses_sit_on_the_period_grid(graph):
    """fleet_sim publishes the poses at exact multiples of its period (stamped with them),
    and a command moves the robot from the moment it arrives: the pose interval in which it
    arrives shows a partial displacement, every later one exactly v·h (no acceleration
    limit in reach here)."""
    g, ear = graph
    h, v = 0.25, 0.4
    odom = ear.record(Odometry, '/fleet/r1/odom')
    g.start('fleet_sim', '-p', 'robots:=[r1]', '-p', 'initial_poses:=[0.0, 0.0, 0.0]',
            '-p', 'kinematics:=holonomic', '-p', f'rate_hz:={1 / h}', '-p', 'max_accel:=1000.0',
            '-p', 'max_speed:=2.0', '-p', 'cmd_timeout_s:=100.0')
    pub = ear.node.create_publisher(Twist, '/fleet/r1/cmd_vel', 10)
    assert ear.spin(20.0, until=lambda: len(odom) >= 4 and pub.get_subscription_count() > 0)
    msg = Twist()
    msg.linear.x = v
    pub.publish(msg)
    assert ear.spin(10.0, until=lambda: odom and odom_xy(odom[-1][1])[0] > 6 * v * h)
    t = np.array([stamp(m) for _, m in odom])
    x = np.array([odom_xy(m)[0] for _, m in odom])
    np.testing.assert_allclose(np.round(t / h) * h, t, atol=1e-6)    # on the grid
    np.testing.assert_allclose(np.diff(t), h, atol=1e-6)             # every grid time once
    dx = np.diff(x)
    first = int(np.argmax(dx > 0))
    assert 0 < dx[first] < v * h - 1e-6, dx[first]                   # from its arrival on
    np.testing.assert_allclose(dx[first + 1:], v * h, rtol=1e-9)


def test_sim_time_starting_late_or_jumping_does_not_stall_fleet_sim(graph):
    """On sim time the node clock reads 0 until the first /clock, then jumps to the bag's
    time (1.78e9 s): a command arriving before /clock must not anchor the pose grid at 0
    (stepping 10⁸ periods to catch up stalled the node: no /fleet/poses at all); a later
    jump forward restarts the grid, logged."""
    from rosgraph_msgs.msg import Clock
    g, ear = graph
    poses = ear.record(Odometry, '/fleet/r1/odom')
    g.start('fleet_sim', '-p', 'robots:=[r1]', '-p', 'initial_poses:=[0.0, 0.0, 0.0]',
            '-p', 'rate_hz:=10.0', '-p', 'use_sim_time:=true', '-p', 'cmd_timeout_s:=100.0')
    cmd = ear.node.create_publisher(Twist, '/fleet/r1/cmd_vel', 10)
    clock = ear.node.create_publisher(Clock, '/clock', 10)
    assert ear.spin(20.0, until=lambda: cmd.get_subscription_count() > 0
                    and clock.get_subscription_count() > 0)
    msg = Twist()
    msg.linear.x = 0.2
    for _ in range(3):                         # commands before any /clock
        cmd.publish(msg)
        ear.spin(0.1)

    def tick(t):
        c = Clock()
        c.clock.sec, c.clock.nanosec = int(t), int(round((t - int(t)) * 1e9))
        clock.publish(c)

    for t0 in (1_781_532_000.0, 1_781_900_000.0):      # sim time starts, then jumps
        seen = len(poses)
        for k in range(40):
            tick(t0 + 0.05 * k)
            ear.spin(0.05)
        assert ear.spin(5.0, until=lambda: len(poses) >= seen + 5), g.output('fleet_sim')
        stamps = np.array([stamp(m) for _, m in poses[seen:]])
        assert (stamps >= t0 - 1e-6).all() and (stamps <= t0 + 2.0).all(), stamps
        np.testing.assert_allclose(np.round(stamps * 10) / 10, stamps, atol=1e-5)
    assert 'clock jumped' in g.output('fleet_sim')


def test_stale_odometry_gives_zero_commands_within_one_period(graph):
    g, ear = graph
    cmds = ear.record(Twist, '/fleet/r1/cmd_vel')
    sim = g.start('fleet_sim', '--params-file', str(CONFIG / 'fleet_sim.yaml'), *sim_args())
    g.start('controller', *controller_args(g))
    assert ear.spin(20.0, until=lambda: any(
        math.hypot(m.linear.x, m.linear.y) > 0.05 for _, m in cmds)), 'no motion commanded'
    stop(sim)
    t_exit = time.time()
    ear.spin(1.5)
    late = [m for t, m in cmds if t > t_exit + 0.5 + 0.1 + 0.15]   # timeout + period + slack
    assert len(late) >= 5
    assert all(m.linear.x == m.linear.y == m.angular.z == 0.0 for m in late)


@pytest.mark.parametrize('kind', ['pairwise', 'shared law with a dog'])
def test_controller_starts_from_a_saved_model_file_alone(graph, kind, tmp_path):
    g, ear = graph
    model, n = g.model, 3
    if kind != 'pairwise':          # a shared-law model file, the dog with its own profile
        from herd_ros.model.shared_law import save_shared_model
        from herd_ros.synthesis.known_truth import make_driven_truth
        model, n = save_shared_model(make_driven_truth(5)[0], tmp_path / 'flock.yaml'), 6
    cmds = ear.record(Twist, '/fleet/robot_1/cmd_vel')
    diags = ear.record(DiagnosticArray, '/diagnostics')
    proc = g.start('controller', '--params-file', str(model))
    assert ear.spin(15.0, until=lambda: len(cmds) >= 5 and diags)
    assert proc.poll() is None, g.output('controller')
    # no odometry at all: every command is an explicit stop
    assert all(m.linear.x == m.linear.y == m.angular.z == 0.0 for _, m in cmds)
    text = ' '.join(s.message for _, d in diags for s in d.status)
    assert f'model of {n} animals' in text


def publish_structure(ear, model):
    """Publish, latched, the estimator's structure for ``model`` (its agents, a 6 × 6 grid
    over ±150 m at dt 1 s); (the latched QoS, the structure)."""
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    structure = ModelStructure(tuple(model.agents), 1.0, 'pairwise', (6, 6),
                               (-150.0, 150.0, -150.0, 150.0), 60.0, 6)
    ear.node.create_publisher(String, '/herd/model/structure', latched).publish(
        String(data=structure.to_json()))
    return latched, structure


def hold_robots(ear, positions: dict):
    """Odometry of robots standing still at ``positions`` ({robot: (x, y)}), every 50 ms."""
    pubs = {r: ear.node.create_publisher(Odometry, f'/fleet/{r}/odom', 10) for r in positions}

    def publish():
        for r, (x, y) in positions.items():
            msg = Odometry()
            msg.header.frame_id = 'map'
            msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
            msg.pose.pose.orientation.w = 1.0
            pubs[r].publish(msg)
    ear.node.create_timer(0.05, publish)


def topic_controller(g, ear, *params):
    """A controller on the estimator's topics for robots r1, r2 (``params``: more
    ``-p`` values), their recorded commands, and the 3-agent truth model and θ to send."""
    cmds = {r: ear.record(Twist, f'/fleet/{r}/cmd_vel') for r in ('r1', 'r2')}
    extra = [a for p in params for a in ('-p', p)]
    g.start('controller', '--params-file', str(CONFIG / 'controller.yaml'),
            '-p', 'robots:=[r1, r2]', '-p', 'model_source:=topic', *extra)
    model = make_truth_model(3, seed=1)
    return cmds, model, np.stack([model.laws[a].theta for a in model.agents])


def test_live_model_from_the_estimator_topic(graph):
    g, ear = graph
    cmds, model, theta = topic_controller(g, ear, 'max_speed:=0.8')
    params = ear.node.create_publisher(Float64MultiArray, '/herd/model/params', 10)
    # what the estimator publishes, latched: how to read the rows (the controller declares
    # none of it)
    _, structure = publish_structure(ear, model)
    assert structure.n_params == theta.shape[1]
    hold_robots(ear, {'r1': (-1.0, 0.0), 'r2': (1.0, 0.0)})   # 2 m apart: well inside repulsion
    assert ear.spin(15.0, until=lambda: len(cmds['r1']) > 5)
    assert all(m.linear.x == 0.0 for _, m in cmds['r1']), 'moved before any model arrived'
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label='agent', size=3, stride=theta.size),
                      MultiArrayDimension(label='param', size=theta.shape[1],
                                          stride=theta.shape[1])]
    msg.data = theta.ravel().tolist()
    params.publish(msg)
    ear.node.create_timer(0.5, lambda: params.publish(msg))
    assert ear.spin(10.0, until=lambda: cmds['r1'][-1][1].linear.x < -0.05)
    # robots 2 m apart repel: r1 is pushed west, r2 east
    assert cmds['r2'][-1][1].linear.x > 0.05


def test_a_robot_waits_until_its_animal_has_been_in_the_herd_long_enough(graph):
    # model_min_updates 3: r1's animal (a0) is on /herd/poses from the start, r2's (a1) only
    # later (a collar that starts late): r2 holds still while r1 follows its law; once a1 has
    # poses in three model steps (dt 1 s), r2 follows too
    from geometry_msgs.msg import Pose, PoseArray

    from herd_ros.nodes.ros_common import tensor_message as matrix
    g, ear = graph
    cmds, model, theta = topic_controller(g, ear, 'max_speed:=0.8', 'model_min_updates:=3')
    publish_structure(ear, model)
    params = ear.node.create_publisher(Float64MultiArray, '/herd/model/params', 10)
    poses = ear.node.create_publisher(PoseArray, '/herd/poses', QoSProfile(depth=100))
    hold_robots(ear, {'r1': (-1.0, 0.0), 'r2': (1.0, 0.0)})   # 2 m apart: they repel
    a1_seen = [False]

    def tick():
        msg = PoseArray()
        msg.header.frame_id = 'map'
        now = ear.node.get_clock().now().nanoseconds
        msg.header.stamp.sec, msg.header.stamp.nanosec = now // 10 ** 9, now % 10 ** 9
        # each robot's animal where the robot is (a waiting robot escorts its animal: here
        # it stays put), a2 (no robot) elsewhere
        for k, (x, y) in enumerate([(-1.0, 0.0), (1.0, 0.0), (2.0, 2.0)]):
            pose = Pose()
            pose.position.x, pose.position.y = (x, y) if (k != 1 or a1_seen[0]) \
                else (math.nan, math.nan)
            msg.poses.append(pose)
        poses.publish(msg)
        params.publish(matrix(theta, ('agent', 'param')))
    ear.node.create_timer(0.25, tick)
    assert ear.spin(15.0, until=lambda: cmds['r1'] and cmds['r1'][-1][1].linear.x < -0.05)
    ear.spin(2.0)
    assert all(m.linear.x == m.linear.y == 0.0 for _, m in cmds['r2']), \
        'r2 followed a law its animal had not been in the herd for'
    a1_seen[0] = True
    assert ear.spin(10.0, until=lambda: cmds['r2'][-1][1].linear.x > 0.05)


@pytest.mark.parametrize('warmup', ['escort', 'hold'])
def test_a_waiting_robot_escorts_its_animal_or_holds_still(graph, warmup):
    # robots that wait for their animals' law (model_min_updates far off): with escort
    # each goes to its animal's pose on /herd/poses (r1 at x = -1 to a0 at x = 5: east;
    # r2 at x = 1 to a1 at x = -5: west), capped at max_speed; with hold they stand still
    from geometry_msgs.msg import Pose, PoseArray

    from herd_ros.nodes.ros_common import tensor_message as matrix
    g, ear = graph
    cmds, model, theta = topic_controller(g, ear, 'max_speed:=0.8', 'model_min_updates:=1000',
                                          f'wait_mode:={warmup}')
    publish_structure(ear, model)
    params = ear.node.create_publisher(Float64MultiArray, '/herd/model/params', 10)
    poses = ear.node.create_publisher(PoseArray, '/herd/poses', QoSProfile(depth=100))
    hold_robots(ear, {'r1': (-1.0, 0.0), 'r2': (1.0, 0.0)})

    def tick():
        msg = PoseArray()
        msg.header.frame_id = 'map'
        now = ear.node.get_clock().now().nanoseconds
        msg.header.stamp.sec, msg.header.stamp.nanosec = now // 10 ** 9, now % 10 ** 9
        for x in (5.0, -5.0, 0.0):
            pose = Pose()
            pose.position.x = x
            msg.poses.append(pose)
        poses.publish(msg)
        params.publish(matrix(theta, ('agent', 'param')))
    ear.node.create_timer(0.25, tick)
    if warmup == 'escort':
        assert ear.spin(15.0, until=lambda: cmds['r1'] and cmds['r2']
                        and cmds['r1'][-1][1].linear.x > 0.7
                        and cmds['r2'][-1][1].linear.x < -0.7)
        assert max(abs(m.linear.x) for r in cmds for _, m in cmds[r]) <= 0.8 + 1e-9
    else:
        assert ear.spin(15.0, until=lambda: len(cmds['r1']) > 20 and len(cmds['r2']) > 20)
        assert all(m.linear.x == m.linear.y == 0.0 for r in cmds for _, m in cmds[r])


def test_the_fleet_starts_together_once_every_robot_has_reported(graph):
    # the same live model and robots as above, but r2's odometry comes 3 s after r1's:
    # r1 alone is not driven (a swarm law of the robots heard so far would be another law)
    g, ear = graph
    diags = ear.record(DiagnosticArray, '/diagnostics')
    cmds, model, theta = topic_controller(g, ear, 'max_speed:=0.8', 'startup_wait_s:=60.0')
    publish_structure(ear, model)
    from herd_ros.nodes.ros_common import tensor_message as matrix
    params = ear.node.create_publisher(Float64MultiArray, '/herd/model/params', 10)
    ear.node.create_timer(0.3, lambda: params.publish(matrix(theta, ('agent', 'param'))))
    hold_robots(ear, {'r1': (-1.0, 0.0)})
    assert ear.spin(15.0, until=lambda: len(cmds['r1']) > 5)
    ear.spin(3.0)
    assert all(m.linear.x == m.linear.y == 0.0 for r in cmds for _, m in cmds[r]), \
        'a robot was driven before the whole fleet had reported'
    text = ' '.join(s.message for _, d in diags for s in d.status)
    assert 'waiting for the odometry of r2' in text
    hold_robots(ear, {'r2': (1.0, 0.0)})              # 2 m apart: they repel at once
    assert ear.spin(10.0, until=lambda: cmds['r1'][-1][1].linear.x < -0.05
                    and cmds['r2'][-1][1].linear.x > 0.05)


def test_live_noise_regimes_from_the_estimator_topic(graph):
    # the estimator's stop-and-go noise (/herd/model/noise_regimes, latched) reaches the
    # robots' law: the controller says which noise its robots draw
    g, ear = graph
    diags = ear.record(DiagnosticArray, '/diagnostics')
    _, model, theta = topic_controller(g, ear, 'noise:=true')
    latched, _ = publish_structure(ear, model)
    q = np.stack([model.laws[a].noise_cov for a in model.agents])
    regimes = np.concatenate([np.stack([0.1 * q, 4.0 * q], axis=1).reshape(3, 2, 4),
                              np.tile([[0.95, 0.05], [0.1, 0.9]], (3, 1, 1))], axis=2)
    params = ear.node.create_publisher(Float64MultiArray, '/herd/model/params', 10)
    noise = ear.node.create_publisher(Float64MultiArray, '/herd/model/noise', 10)
    regime_pub = ear.node.create_publisher(Float64MultiArray, '/herd/model/noise_regimes',
                                           latched)
    from herd_ros.nodes.ros_common import tensor_message as matrix

    def publish():
        noise.publish(matrix(q.reshape(3, 4), ('agent', 'qxx_qxy_qyx_qyy')))
        regime_pub.publish(matrix(regimes, ('agent', 'regime', 'q4_transition')))
        params.publish(matrix(theta, ('agent', 'param')))
    ear.node.create_timer(0.5, publish)

    def said(text):
        return any(text in s.message for _, d in diags for s in d.status)
    assert ear.spin(15.0, until=lambda: said('stop-and-go noise in 2 regimes')), \
        [s.message for _, d in diags[-3:] for s in d.status]


def test_live_home_pull_from_the_estimator_topic(graph):
    # each animal's home pull (/herd/model/home) joins the robots' law: a law of damping
    # alone leaves robots standing until the pull arrives, then drives them towards their
    # animals' ranges
    g, ear = graph
    cmds, model, theta = topic_controller(g, ear, 'max_speed:=0.8')
    theta[:, 1:] = 0.0                           # no pair law, no field: damping alone
    publish_structure(ear, model)
    from herd_ros.nodes.ros_common import tensor_message as matrix
    params = ear.node.create_publisher(Float64MultiArray, '/herd/model/params', 10)
    home = ear.node.create_publisher(Float64MultiArray, '/herd/model/home', 10)
    hold_robots(ear, {'r1': (0.0, -1.0), 'r2': (0.0, 1.0)})
    ear.node.create_timer(0.3, lambda: params.publish(matrix(theta, ('agent', 'param'))))
    assert ear.spin(15.0, until=lambda: len(cmds['r1']) > 20)
    assert all(abs(m.linear.x) < 1e-9 for _, m in cmds['r1'][-5:]), 'moved without a pull'
    # centres 30 m east (r1's animal) and 30 m west (r2's), gain 0.05 per step, ranges of
    # std 2 m (the robots, 30 m off, are far beyond their edge)
    rows = np.zeros((3, 10))
    rows[:, 0] = [30.0, -30.0, 0.0]
    rows[:, 2] = rows[:, 5] = 0.05
    rows[:, 6] = rows[:, 9] = 4.0
    bad = rows.copy()
    bad[1, 3] = np.nan                           # malformed: one clear warning, ignored
    home.publish(matrix(bad, ('agent', 'mux')))
    home.publish(matrix(rows[:, :6], ('agent', 'mux')))
    ear.spin(1.0)
    assert all(abs(m.linear.x) < 1e-9 for _, m in cmds['r1'][-3:]), 'a bad home was taken'
    ear.node.create_timer(0.3, lambda: home.publish(matrix(rows, ('agent', 'mux'))))
    assert ear.spin(10.0, until=lambda: cmds['r1'][-1][1].linear.x > 0.05
                    and cmds['r2'][-1][1].linear.x < -0.05)
    assert '/herd/model/home: expected 30 finite numbers' in g.output('controller')


def test_bad_parameters_exit_with_one_clear_line(ros_env, console_script):
    for name, args, needle in [
            ('fleet_sim', ['-p', 'kinematics:=tank'], 'kinematics'),
            ('fleet_sim', ['-p', 'robots:=[a, b]', '-p', 'initial_poses:=[0.0, 1.0]'],
             'initial_poses'),
            ('controller', ['-p', 'mode:=dance'], 'mode'),
            ('controller', [], 'params-file')]:
        out = subprocess.run([console_script(name), '--ros-args', *args], env=ros_env,
                             capture_output=True, text=True, timeout=30)
        assert out.returncode == 2, out.stderr
        assert needle in out.stderr and 'Traceback' not in out.stderr
