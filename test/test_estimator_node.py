"""The `estimator` node as users run it: the installed console script in a subprocess, fed
PoseArray snapshots of a known-parameter herd by an in-process publisher (issue 4,
acceptance 3 and 4). Expectations come from the known truth, never from the node's code.
"""
import os
import signal
import subprocess
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import Pose, PoseArray  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float64MultiArray, String  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from herd_ros.model.model_file import load_model  # noqa: E402
from herd_ros.model.model_structure import ModelStructure  # noqa: E402
from herd_ros.nodes.ros_common import seconds_to_stamp  # noqa: E402
from herd_ros.simulation.herd_simulator import simulate  # noqa: E402
from herd_ros.synthesis.known_truth import initial_positions, make_truth_model  # noqa: E402

BOUNDS = (-75.0, 75.0, -75.0, 75.0)
GRID = (6, 6)
STEPS = 3000


@pytest.fixture(scope='module')
def herd():
    truth = make_truth_model(3, seed=1, grid=GRID, bounds=BOUNDS)
    run = simulate(truth, STEPS, initial_positions(truth, seed=1, spread=25), seed=5)
    return truth, run


@pytest.fixture
def ros(ros_env):
    """A fresh rclpy context on the subprocess' domain, shut down afterwards."""
    os.environ['ROS_DOMAIN_ID'] = ros_env['ROS_DOMAIN_ID']
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('estimator_test_feeder', context=context)
    yield node, ros_env
    node.destroy_node()
    rclpy.shutdown(context=context)


class Feeder:
    """Publishes snapshots and collects what the estimator publishes."""

    def __init__(self, node):
        self.node = node
        self.pub = None
        self.renew_publisher()
        self.params = None
        self.samples = {}
        self.received = -1  # snapshots the estimator reports having received
        node.create_subscription(Float64MultiArray, '/herd/model/params', self._on_params, 10)
        self.home = self.place = None
        node.create_subscription(Float64MultiArray, '/herd/model/home',
                                 lambda msg: setattr(self, 'home', msg), 10)
        node.create_subscription(Float64MultiArray, '/herd/model/place',
                                 lambda msg: setattr(self, 'place', msg), 10)
        self.structure = None      # latched: a subscriber that joins late still gets it
        node.create_subscription(String, '/herd/model/structure', self._on_structure,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)
        self.regimes = None        # latched as well
        node.create_subscription(Float64MultiArray, '/herd/model/noise_regimes',
                                 self._on_regimes,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.save = node.create_client(Trigger, '/estimator/save_model')
        self.executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)

    def renew_publisher(self):
        """A fresh /herd/poses writer with an empty history. The reliable writer keeps up to
        1000 snapshots; once on CI, 47 snapshots past the checkpoint reached a restarted
        estimator before its first diagnostics; nothing else could have sent them."""
        if self.pub is not None:
            self.node.destroy_publisher(self.pub)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.node.create_publisher(PoseArray, '/herd/poses', qos)

    def _on_params(self, msg):
        self.params = msg

    def _on_regimes(self, msg):
        self.regimes = msg

    def _on_structure(self, msg):
        self.structure = ModelStructure.from_json(msg.data)

    def _on_diag(self, msg):
        for s in msg.status:
            if s.name == 'estimator: herd clock':
                self.received = max(self.received, int(
                    next(kv.value for kv in s.values if kv.key == 'snapshots')))
            for kv in s.values:
                if kv.key == 'samples':
                    self.samples[s.hardware_id] = int(kv.value)

    def spin(self, seconds, until=None):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)
            if until is not None and until():
                return True
        return until is None

    def wait_for_estimator(self, times, positions, timeout=20.0):
        """Handshake: repeat the first snapshot (repeats are ignored as not later) until the
        estimator reports receiving it — discovery of a restarted node may lag."""
        self.received = -1
        end = time.monotonic() + timeout
        while self.received < 1:
            assert time.monotonic() < end, 'the estimator never received /herd/poses'
            self.pub.publish(self.snapshot(times[0], positions[0]))
            self.spin(0.1)
        return self.received

    @staticmethod
    def snapshot(t, p):
        msg = PoseArray()
        msg.header.stamp = seconds_to_stamp(float(t))
        msg.header.frame_id = 'map'
        for x, y in p:
            pose = Pose()
            pose.position.x, pose.position.y = float(x), float(y)
            pose.orientation.w = 1.0
            msg.poses.append(pose)
        return msg

    def publish(self, times, positions):
        """Publish the snapshots after the first, keeping < 400 in flight (queue depth 1000)."""
        base = self.base = self.wait_for_estimator(times, positions)
        for k in range(1, len(times)):
            self.pub.publish(self.snapshot(times[k], positions[k]))
            while k - (self.received - base) > 400:
                self.spin(0.01)
            if k % 50 == 0:
                self.executor.spin_once(timeout_sec=0)

    def call_save(self):
        assert self.save.wait_for_service(timeout_sec=10.0)
        future = self.save.call_async(Trigger.Request())
        assert self.spin(20.0, future.done)
        return future.result()


def start_estimator(console_script, env, tmp_path, agents):
    args = [console_script('estimator'), '--ros-args',
            '-p', f'agents:=[{",".join(agents)}]', '-p', 'dt:=1.0',
            '-p', f'field_grid:=[{GRID[0]},{GRID[1]}]',
            '-p', f'field_bounds:=[{",".join(str(b) for b in BOUNDS)}]',
            '-p', f'model_out:={tmp_path / "model.yaml"}',
            '-p', f'checkpoint_path:={tmp_path / "estimator.ckpt.npz"}',
            '-p', 'checkpoint_period_s:=0.5', '-p', 'diagnostics_period_s:=0.3']
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def stop(proc, sig=signal.SIGINT):
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.communicate()


def test_node_converges_to_the_truth(ros, herd, console_script, tmp_path):
    node, env = ros
    truth, run = herd
    proc = start_estimator(console_script, env, tmp_path, run.agents)
    try:
        feeder = Feeder(node)
        feeder.publish(run.times, run.positions)
        sent_updates = STEPS - 2
        # (a snapshot lost in transport only breaks the chain: fewer samples, no harm)
        assert feeder.spin(60.0, lambda: min(feeder.samples.get(a, 0) for a in run.agents)
                           >= 0.9 * sent_updates), feeder.samples
        assert feeder.spin(5.0, lambda: feeder.params is not None)
        settled, end = None, time.monotonic() + 20.0     # until every snapshot is learned
        while settled != dict(feeder.samples) and time.monotonic() < end:
            settled = dict(feeder.samples)
            feeder.spin(1.0)
        dims = feeder.params.layout.dim
        assert [d.label for d in dims] == ['agent', 'param']
        theta = np.array(feeder.params.data).reshape(dims[0].size, dims[1].size)
        # what a reader needs to read θ comes with it (issue 26): the run's agents in order,
        # the clock step, the grid the node was started with
        assert feeder.spin(5.0, lambda: feeder.structure is not None)
        st = feeder.structure
        assert st.agents == tuple(run.agents) and st.law == 'pairwise'
        assert st.field_grid == GRID and st.field_bounds == BOUNDS
        assert st.dt == pytest.approx(float(run.times[1] - run.times[0]))
        assert theta.shape == (len(run.agents), st.n_params)
        # the published field is the file's: a centre whose cell an animal visited fewer
        # than min_visits (10) times is 0 (counted here from the positions sent)
        n, K = len(run.agents), GRID[0] * GRID[1]
        cell_w, cell_h = (BOUNDS[1] - BOUNDS[0]) / GRID[0], (BOUNDS[3] - BOUNDS[2]) / GRID[1]
        for i in range(n):
            p = run.positions[:-2, i]
            cells = (np.floor((p[:, 1] - BOUNDS[2]) / cell_h) * GRID[0]
                     + np.floor((p[:, 0] - BOUNDS[0]) / cell_w)).astype(int)
            rare = np.bincount(cells, minlength=K)[:K] < 10
            assert rare.any()
            field = theta[i, 2 * n - 1:].reshape(2, K)
            assert (field[:, rare] == 0.0).all() and (field[:, ~rare] != 0.0).any()
        # each animal's range and home pull: μ_i and Σ_i the mean and covariance of its
        # positions, K_i = Δt/(2(1 − a_i)) Q_i Σ_i⁻¹ (space_use_field, S2) — here from the
        # truth's a_i, Q_i
        assert feeder.spin(5.0, lambda: feeder.home is not None)
        dims = feeder.home.layout.dim
        assert [d.label for d in dims] == ['agent', 'mux_muy_kxx_kxy_kyx_kyy_sxx_sxy_syx_syy']
        home = np.array(feeder.home.data).reshape(n, 10)
        for i, a in enumerate(run.agents):
            p = run.positions[:, i]
            np.testing.assert_allclose(home[i, :2], p.mean(axis=0), atol=0.05 * p.std())
            sigma = np.cov(p.T)
            np.testing.assert_allclose(home[i, 6:].reshape(2, 2), sigma,
                                       rtol=0.2, atol=0.1 * np.abs(sigma).max())
            law = truth.laws[a]
            expected = st.dt / (2 * (1 - law.damping)) * law.noise_cov @ np.linalg.inv(sigma)
            np.testing.assert_allclose(home[i, 2:6].reshape(2, 2), expected,
                                       rtol=0.15, atol=0.05 * np.abs(expected).max())
        # ... and its place in the herd: the same for its offset from the others' centroid
        assert feeder.place is not None
        place = np.array(feeder.place.data).reshape(n, 10)
        offsets = run.positions - (run.positions.sum(1, keepdims=True) - run.positions) / (n - 1)
        for i in range(n):
            d = offsets[:, i]
            np.testing.assert_allclose(place[i, :2], d.mean(axis=0), atol=0.05 * d.std())
            np.testing.assert_allclose(place[i, 6:].reshape(2, 2), np.cov(d.T),
                                       rtol=0.2, atol=0.1 * np.abs(np.cov(d.T)).max())
        result = feeder.call_save()
        assert result.success, result.message
        # the stop-and-go noise, refitted every regime_refit_every updates: the truth's noise
        # is Gaussian, so one regime, whose covariance is the truth's Q_i within 15 %
        assert feeder.spin(5.0, lambda: feeder.regimes is not None)
        dims = feeder.regimes.layout.dim
        assert [d.label for d in dims] == ['agent', 'regime', 'q4_transition']
        assert [d.size for d in dims] == [len(run.agents), 1, 5]
        rows = np.array(feeder.regimes.data).reshape(len(run.agents), 5)
        np.testing.assert_allclose(rows[:, 4], 1.0)
        for i, a in enumerate(run.agents):
            q = truth.laws[a].noise_cov
            assert abs(rows[i, 0] + rows[i, 3] - np.trace(q)) < 0.15 * np.trace(q), (a, rows[i])
    finally:
        out, err = stop(proc)
    assert 'Traceback' not in err, err
    assert 'noise regimes: 1 by BIC' in err
    saved = load_model(tmp_path / 'model.yaml')
    for i, a in enumerate(run.agents):
        true = truth.laws[a].damping
        assert abs(theta[i, 0] - true) / true < 0.03, (a, theta[i, 0], true)  # on the topic
        law = saved.laws[a]
        assert abs(law.damping - true) / true < 0.03, (a, law.damping, true)   # in the file
        assert law.neighbors == [b for b in run.agents if b != a]
        # the learned one-step prediction is as good as the truth's (within 5 %)
    from herd_ros.simulation.prediction import one_step_rms
    assert one_step_rms(saved, [run])['model']['herd'] <= 1.05 * \
        one_step_rms(truth, [run])['model']['herd']


def test_kill_9_resumes_from_the_checkpoint(ros, herd, console_script, tmp_path):
    node, env = ros
    truth, run = herd
    ckpt = tmp_path / 'estimator.ckpt.npz'
    half = 1500
    proc = start_estimator(console_script, env, tmp_path, run.agents)
    try:
        feeder = Feeder(node)
        feeder.publish(run.times[:half], run.positions[:half])
        assert feeder.spin(20.0, lambda: min(feeder.samples.get(a, 0) for a in run.agents)
                           >= 0.9 * half), feeder.samples
        feeder.spin(1.2)  # at least one checkpoint period after the data
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    with np.load(ckpt) as z:
        checkpointed = z['rls_samples'].copy()
        theta_before = z['rls_theta'].copy()
    assert checkpointed.min() >= 0.9 * half
    feeder.samples.clear()
    feeder.renew_publisher()   # the restarted node sees only what is published from now on
    proc = start_estimator(console_script, env, tmp_path, run.agents)
    try:
        assert feeder.spin(20.0, lambda: len(feeder.samples) == 3), 'no diagnostics after restart'
        resumed = np.array([feeder.samples[a] for a in run.agents])
        assert (resumed == checkpointed).all(), (resumed, checkpointed)   # the count continues
        feeder.publish(run.times[half:], run.positions[half:])
        assert feeder.spin(20.0, lambda: min(feeder.samples.values())
                           >= checkpointed.min() + 0.9 * (STEPS - half - 2)), feeder.samples
    finally:
        out, err = stop(proc)
    assert 'resumed from checkpoint' in err + out
    assert 'Traceback' not in err, err
    with np.load(ckpt) as z:  # written on shutdown; θ continued from where it stopped
        assert z['rls_samples'].min() > checkpointed.min()
        assert np.allclose(z['rls_theta'][:, 0], theta_before[:, 0], atol=0.05)


def test_a_replay_started_over_is_a_new_session(ros, herd, console_script, tmp_path):
    """Issue 26: the same recording twice with the same checkpoint (a second launch on the
    same bag, a looping replay): the second run's data time is far behind the checkpoint;
    the estimator sets the checkpoint aside, starts afresh and learns — parameters are
    published again and the sample counts start over."""
    node, env = ros
    truth, run = herd
    ckpt = tmp_path / 'estimator.ckpt.npz'
    n = 400
    proc = start_estimator(console_script, env, tmp_path, run.agents)
    try:
        feeder = Feeder(node)
        feeder.publish(run.times[:n], run.positions[:n])
        assert feeder.spin(20.0, lambda: min(feeder.samples.get(a, 0) for a in run.agents)
                           >= 0.9 * n), feeder.samples
        # the checkpoint written at the stop is to hold the whole run: every snapshot taken
        assert feeder.spin(20.0, lambda: feeder.received - feeder.base >= n - 1), \
            (feeder.received, feeder.base)
    finally:
        stop(proc)
    assert ckpt.is_file()
    proc = start_estimator(console_script, env, tmp_path, run.agents)
    try:
        feeder.params = None
        feeder.samples.clear()
        feeder.publish(run.times[:n], run.positions[:n])
        assert feeder.spin(20.0, lambda: feeder.params is not None), 'no parameters published'
        assert feeder.spin(20.0, lambda: min(feeder.samples.get(a, 0) for a in run.agents)
                           >= 0.9 * n), feeder.samples
        assert max(feeder.samples.values()) <= n           # counted afresh, not continued
    finally:
        out, err = stop(proc)
    assert 'a new session' in err + out, err
    assert (tmp_path / 'estimator.ckpt.session-1.npz').is_file()    # set aside, not deleted
    assert 'Traceback' not in err, err
    # the checkpoint says which recording it learned from: the first run's data time
    import json
    with np.load(tmp_path / 'estimator.ckpt.session-1.npz') as z:
        session = json.loads(str(z['session']))
    assert session['first_time'] == pytest.approx(run.times[0])
    assert session['last_time'] == pytest.approx(run.times[n - 1])
    assert 'resumed from checkpoint' in err + out and 'data time' in err + out
