"""The `gps_ingest` node as users run it (issue 3, acceptance 5): the installed console script
in a subprocess, fed NavSatFix by this test process over loopback-only DDS.

Expectations come from known truth (positions of simulated collars, counts of the bad
messages sent) or from the offline path (`trajectory_from_fixes`), never from the node.
"""
import math
import os
import signal
import subprocess
import time

import numpy as np
import pandas as pd
import pytest

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import PoseArray  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import NavSatFix, NavSatStatus  # noqa: E402

from herd_ros.ingest.geodesy import enu_to_geodetic  # noqa: E402
from herd_ros.ingest.pipeline import trajectory_from_fixes  # noqa: E402
from herd_ros.nodes.ros_common import seconds_to_stamp, stamp_to_seconds  # noqa: E402

DATUM = (46.8, 7.15, 550.0)
T0 = 1_700_000_000.0
WARN = DiagnosticStatus.WARN[0] if isinstance(DiagnosticStatus.WARN, bytes) else 1


@pytest.fixture
def ros(ros_env):
    """A fresh rclpy context on the subprocess' domain, shut down afterwards."""
    os.environ['ROS_DOMAIN_ID'] = ros_env['ROS_DOMAIN_ID']
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('gps_ingest_test_collars', context=context)
    yield node, ros_env
    node.destroy_node()
    rclpy.shutdown(context=context)


def start_node(console_script, env, tmp_path, agents, **params):
    args = [console_script('gps_ingest'), '--ros-args',
            '-p', f'agents:=[{", ".join(agents)}]', '-p', 'diagnostics_period_s:=0.3']
    for name, value in params.items():
        if isinstance(value, (list, tuple)):
            value = '[' + ', '.join(repr(float(v)) for v in value) + ']'
        args += ['-p', f'{name}:={value}']
    log = open(tmp_path / 'gps_ingest.log', 'w')
    proc = subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT, text=True)
    proc.log_path = tmp_path / 'gps_ingest.log'
    return proc


def stop(proc):
    """SIGINT, then SIGKILL if it does not stop; returns the exit status."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


SHARED = {'fix_topic': '/herd/fix', 'odom_topic': '/herd/odom'}


class Collars:
    """Publishes fixes for the agents and collects what gps_ingest publishes; ``shared``:
    on the node's fix_topic / odom_topic (:data:`SHARED`), the collar in the frames, named
    each way the node accepts (``<agent>``, ``<agent>_gps``, ``<agent>/gps``)."""

    def __init__(self, node, agents, shared=False):
        self.node = node
        self.agents = list(agents)
        self.shared = shared
        self.odom = {a: [] for a in agents}
        self.poses = []
        self.diag = {}            # hardware_id or name -> list of (level, message, values)
        if shared:
            pub = node.create_publisher(NavSatFix, SHARED['fix_topic'],
                                        qos_profile_sensor_data)
            self.pubs = dict.fromkeys(agents, pub)
            self.frames = {a: (a, f'{a}_gps', f'{a}/gps')[k % 3] for k, a in enumerate(agents)}
            node.create_subscription(Odometry, SHARED['odom_topic'],
                                     lambda m: self.odom[m.child_frame_id].append(m), 1000)
        else:
            self.pubs = {a: node.create_publisher(NavSatFix, f'/herd/{a}/fix',
                                                  qos_profile_sensor_data) for a in agents}
            self.frames = {a: f'{a}/gps' for a in agents}
            for a in agents:
                node.create_subscription(Odometry, f'/herd/{a}/odom',
                                         lambda m, a=a: self.odom[a].append(m), 100)
        node.create_subscription(PoseArray, '/herd/poses', self.poses.append, 100)
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)

    def _on_diag(self, msg):
        for s in msg.status:
            level = s.level[0] if isinstance(s.level, bytes) else int(s.level)
            values = {kv.key: kv.value for kv in s.values}
            self.diag.setdefault(s.hardware_id or s.name, []).append((level, s.message, values))

    def spin(self, seconds, until=None):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)
            if until is not None and until():
                return True
        return until is None

    def wait_for_node(self, proc, timeout=30.0):
        def matched():
            return (all(p.get_subscription_count() > 0 for p in self.pubs.values())
                    and self.node.count_publishers('/herd/poses') > 0
                    and self.node.count_publishers('/diagnostics') > 0
                    and all(self.node.count_publishers(
                        SHARED['odom_topic'] if self.shared else f'/herd/{a}/odom') > 0
                            for a in self.agents))
        ok = self.spin(timeout, lambda: matched() or proc.poll() is not None)
        assert proc.poll() is None, f'gps_ingest exited: {proc.log_path.read_text()}'
        assert ok, 'gps_ingest never matched the test topics'
        self.spin(0.5)  # let the node's side of the discovery settle too

    def publish(self, fixes):
        """fixes: rows (agent, stamp, lat, lon, alt, status, cov_type, variance)."""
        for k, (agent, stamp, lat, lon, alt, status, cov_type, var) in enumerate(fixes):
            msg = NavSatFix()
            msg.header.stamp = seconds_to_stamp(stamp)
            msg.header.frame_id = self.frames[agent]
            msg.status.status = int(status)
            msg.status.service = NavSatStatus.SERVICE_GPS
            msg.latitude, msg.longitude, msg.altitude = float(lat), float(lon), float(alt)
            msg.position_covariance = [var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, 4 * var]
            msg.position_covariance_type = int(cov_type)
            self.pubs[agent].publish(msg)
            self.spin(0.005)     # pace: best effort, the node keeps the last 50 per topic

    def last_status(self, key):
        return self.diag.get(key, [None])[-1]

    def counted(self, agent):
        """Fixes the node has accounted for (accepted or rejected), from its diagnostics."""
        last = self.last_status(agent)
        if last is None:
            return 0
        v = last[2]
        return sum(int(v[k]) for k in v if k == 'accepted' or k.startswith('rejected_'))


def truth_a(t):
    """cow_a walks east at 0.5 m/s (ENU m about DATUM), t in s since T0."""
    return np.array([10.0 + 0.5 * t, -20.0])


TRUTH_B = np.array([-30.0, 40.0])


def fix_row(agent, stamp, enu, noise, status=NavSatStatus.STATUS_FIX, cov_type=2, var=1.0,
            alt=DATUM[2]):
    lat, lon, _ = enu_to_geodetic(enu[0] + noise[0], enu[1] + noise[1], 0.0, *DATUM)
    return (agent, stamp, float(lat), float(lon), alt, status, cov_type, var)


def test_odometry_poses_and_bad_messages(ros, console_script, tmp_path):
    node, env = ros
    agents = ['cow_a', 'cow_b']
    rng = np.random.default_rng(3)
    good, n_steps = [], 60
    for k in range(n_steps):
        ta, tb = k + 0.25, k + 0.5
        good.append(fix_row('cow_a', T0 + ta, truth_a(ta), rng.normal(0, 1.0, 2)))
        # cow_b: no vertical solution (NaN altitude is valid) and covariance UNKNOWN
        good.append(fix_row('cow_b', T0 + tb, TRUTH_B, rng.normal(0, 1.0, 2), cov_type=0,
                            alt=math.nan))
    bad_stamps = [T0 + 40.75, T0 + 41.75, T0 + 42.75, T0 + 5.0]
    nan_lat = ('cow_a', bad_stamps[0], math.nan, 7.15, 550.0, 0, 2, 1.0)
    no_fix = fix_row('cow_a', bad_stamps[1], truth_a(41.75), (0, 0),
                     status=NavSatStatus.STATUS_NO_FIX)
    jump = fix_row('cow_a', bad_stamps[2], truth_a(42.75), (500.0, 0.0))
    backwards = fix_row('cow_a', bad_stamps[3], truth_a(5.0), (0, 0))
    future = fix_row('cow_b', 2.1e9, TRUTH_B, (0, 0))   # year 2036: a broken stamp
    stream = sorted(good, key=lambda f: f[1])
    cut = next(i for i, f in enumerate(stream) if f[1] > T0 + 40.5)
    stream = stream[:cut] + [nan_lat] + stream[cut:cut + 2] + [no_fix] \
        + stream[cut + 2:cut + 4] + [jump, backwards, future] + stream[cut + 4:]

    collars = Collars(node, agents)
    proc = start_node(console_script, env, tmp_path, agents, dt=1.0, stale_after=5.0,
                      accel_std=0.05, default_position_std=5.0, datum=DATUM)
    try:
        collars.wait_for_node(proc)
        collars.publish(stream)
        sent = {a: sum(f[0] == a for f in stream) for a in agents}
        collars.spin(15.0, lambda: all(collars.counted(a) == sent[a] for a in agents))
        assert proc.poll() is None, 'gps_ingest died on bad input'
        assert {a: collars.counted(a) for a in agents} == sent, 'fixes were lost'

        # -- Odometry: one per accepted fix, stamped with it, close to the truth ----------
        good_stamps = {round(f[1], 6) for f in good}
        for agent in agents:
            odoms = collars.odom[agent]
            # every accepted fix gave one odometry; the good fixes are nearly all accepted
            # (this noise draw makes cow_a's first velocity 2.8 m/s wrong: four gate
            # rejections, then the filter re-initialises on them, as designed)
            assert len(odoms) == int(collars.last_status(agent)[2]['accepted'])
            assert len(odoms) >= n_steps - 5
            for m in odoms:
                assert m.header.frame_id == 'map' and m.child_frame_id == agent
                assert round(stamp_to_seconds(m.header.stamp), 6) in good_stamps
        last_a, last_b = collars.odom['cow_a'][-1], collars.odom['cow_b'][-1]
        t_a = stamp_to_seconds(last_a.header.stamp) - T0
        assert t_a == pytest.approx(n_steps - 1 + 0.25)
        pos_a = np.array([last_a.pose.pose.position.x, last_a.pose.pose.position.y])
        cov_a = np.array(last_a.pose.covariance).reshape(6, 6)[:2, :2]
        err = pos_a - truth_a(t_a)
        assert np.linalg.norm(err) < 1.5
        assert 0.01 < cov_a[0, 0] < 1.0 and 0.01 < cov_a[1, 1] < 1.0   # below R = 1 m²
        assert err @ np.linalg.solve(cov_a, err) < 25.0                  # consistent
        assert np.hypot(last_a.twist.twist.linear.x - 0.5, last_a.twist.twist.linear.y) < 0.25
        # the twist covariance is the chosen model's and consistent with the twist's error:
        # small under an IOU; under a random walk (the IOU not the closer predictor beyond
        # chance on its 39 fixes: 7 % closer here, 1 m noise against 0.5 m of motion a fix) it
        # says the velocity is hardly known
        tw = np.array(last_a.twist.covariance).reshape(6, 6)[:2, :2]
        v_err = np.array([last_a.twist.twist.linear.x - 0.5, last_a.twist.twist.linear.y])
        assert tw[0, 0] > 0 and tw[1, 1] > 0
        assert v_err @ np.linalg.solve(tw, v_err) < 25.0
        pos_b = np.array([last_b.pose.pose.position.x, last_b.pose.pose.position.y])
        assert np.linalg.norm(pos_b - TRUTH_B) < 1.5
        # no odometry at the bad fixes, and it goes on after them
        assert not any(round(stamp_to_seconds(m.header.stamp), 6) in
                       {round(s, 6) for s in bad_stamps} for m in collars.odom['cow_a'])
        assert sum(stamp_to_seconds(m.header.stamp) > bad_stamps[2]
                   for m in collars.odom['cow_a']) >= 15

        # -- PoseArray: every tick k·dt once, in order, agents in order, near the truth ---
        ticks = np.array([stamp_to_seconds(m.header.stamp) for m in collars.poses])
        assert len(ticks) >= n_steps - 3
        assert ticks[0] == pytest.approx(T0 + 1.0)   # first multiple of dt after T0 + 0.25
        np.testing.assert_allclose(np.diff(ticks), 1.0, atol=1e-6)
        for m, tick in zip(collars.poses, ticks):
            assert m.header.frame_id == 'map' and len(m.poses) == 2
            if tick - T0 < 40:      # the prior follows the fixes; refits at fix 20, 40
                continue
            pa = np.array([m.poses[0].position.x, m.poses[0].position.y])
            pb = np.array([m.poses[1].position.x, m.poses[1].position.y])
            assert np.linalg.norm(pa - truth_a(tick - T0)) < 2.0
            assert np.linalg.norm(pb - TRUTH_B) < 2.0

        # -- Diagnostics: the bad fixes are counted by reason and raised a WARN -----------
        level, _, values = collars.last_status('cow_a')
        assert int(values['rejected_nan']) == 1
        assert int(values['rejected_no_fix']) == 1
        assert int(values['rejected_time']) == 1
        assert int(values['rejected_speed']) + int(values['rejected_gate']) >= 1
        assert any(lv == WARN for lv, _, _ in collars.diag['cow_a'])
        assert values['stale'] == 'False'
        # a stamp decades ahead is refused and does not drag the clock (checked above)
        assert int(collars.last_status('cow_b')[2]['rejected_future']) == 1
        assert proc.poll() is None
    finally:
        rc = stop(proc)
    assert rc == 0, proc.log_path.read_text()


@pytest.mark.parametrize('topics', ['per-collar', 'shared'])
def test_same_snapshots_as_the_offline_path(ros, console_script, tmp_path, topics):
    """Noisy, irregular fixes with jumps, NaN and NO_FIX; no datum parameter; the first
    round published in reverse stamp order: the node must choose the offline datum and give
    the offline snapshots. Shared: every collar on one fix topic and one odometry topic,
    plus a fix of a collar not in ``agents`` and a message that is not a NavSatFix, each
    counted and dropped."""
    node, env = ros
    agents = ['cow_a', 'cow_b', 'cow_c']
    rng = np.random.default_rng(11)
    rows = []
    for i, agent in enumerate(agents):
        t = T0 + 0.3 * i + np.cumsum(rng.uniform(0.4, 1.6, 120))
        v = np.array([0.3 * (i - 1), 0.2])
        p = np.array([20.0 * i, -10.0 * i]) + (t - T0)[:, None] * v
        z = p + rng.normal(0, 3.0, p.shape)
        z[rng.random(len(t)) < 0.03] += 50.0
        cov_type = 2 if agent == 'cow_a' else 0
        for k in range(len(t)):
            status = NavSatStatus.STATUS_NO_FIX if k in (7, 60) else NavSatStatus.STATUS_FIX
            row = fix_row(agent, float(t[k]), z[k], (0.0, 0.0), status=status,
                          cov_type=cov_type, var=9.0)
            if k == 30:
                row = row[:2] + (math.nan,) + row[3:]
            rows.append(row)
    rows.sort(key=lambda r: r[1])
    # the first fix of all is NO_FIX (never the datum); the first round arrives reversed
    rows[0] = rows[0][:5] + (NavSatStatus.STATUS_NO_FIX,) + rows[0][6:]
    stream = rows[:3][::-1] + rows[3:]
    table = pd.DataFrame(rows, columns=['agent', 'time', 'lat', 'lon', 'alt', 'status',
                                        'position_covariance_type', 'cov_ee'])
    table['cov_nn'] = table['cov_ee']
    table['cov_en'] = 0.0
    # the collars' motion models refitted as their fixes arrive (the node's default),
    # about the given prior: the node must refit at the same fixes as the offline path
    params = dict(dt=2.0, stale_after=6.0, accel_std=0.1, default_position_std=4.0,
                  gate_probability=0.995, max_speed=3.0, motion_model='fit')
    offline = trajectory_from_fixes(table, datum=None, trim=False, agents=agents, **params)

    shared = topics == 'shared'
    collars = Collars(node, agents, shared=shared)
    if shared:         # a frame that names cow_c only once made a ROS name (agent_ids)
        collars.frames['cow_c'] = 'cow c'
    proc = start_node(console_script, env, tmp_path, agents, **params,
                      **(SHARED if shared else {}))
    try:
        collars.wait_for_node(proc)
        collars.publish(stream[:200])
        if shared:
            stranger = fix_row('cow_x', T0 + 60.0, (0.0, 0.0), (0.0, 0.0))
            collars.frames['cow_x'] = 'cow_x'
            collars.pubs['cow_x'] = collars.pubs['cow_a']
            collars.publish([stranger])
            collars.pubs['cow_a'].publish(b'\x00\x01\x00\x00' + bytes(9))   # not a NavSatFix
        collars.publish(stream[200:])
        sent = {a: sum(f[0] == a for f in stream) for a in agents}
        collars.spin(15.0, lambda: all(collars.counted(a) == sent[a] for a in agents))
        assert {a: collars.counted(a) for a in agents} == sent, 'fixes were lost'
        if shared:
            collars.spin(5.0, lambda: int(collars.last_status('gps_ingest')[2]
                                          ['unknown_collar_fixes']) == 1)
            values = collars.last_status('gps_ingest')[2]
            assert int(values['unknown_collar_fixes']) == 1
            assert values['last_unknown_frame'] == 'cow_x'
            assert int(values['message_errors']) == 1
            # each problem said once, in the report of the period it happened in
            warned = ' | '.join(m for level, m, _ in collars.diag['gps_ingest']
                                if level == WARN)
            assert warned.count('1 fix of unknown collars dropped') == 1, warned
            assert warned.count('1 bad message dropped') == 1, warned
            assert proc.poll() is None
    finally:
        rc = stop(proc)
    assert rc == 0
    log = proc.log_path.read_text()
    assert log.count('datum (first valid fix)') == 1, log
    lat0, lon0 = (float(s) for s in log.split('datum (first valid fix): lat ')[1]
                     .split(' alt')[0].split(' lon '))
    assert (lat0, lon0) == pytest.approx(offline.meta['datum'][:2], abs=1e-8)

    index = {round(t, 6): k for k, t in enumerate(offline.times)}
    compared = 0
    for m in collars.poses:
        k = index.get(round(stamp_to_seconds(m.header.stamp), 6))
        assert k is not None, 'a tick the offline clock does not have'
        node_xy = np.array([[p.position.x, p.position.y] for p in m.poses])
        np.testing.assert_array_equal(np.isnan(node_xy), np.isnan(offline.positions[k]))
        np.testing.assert_allclose(node_xy, offline.positions[k], atol=1e-6, rtol=0,
                                   equal_nan=True)
        compared += 1
    assert compared >= 40
    for agent in agents:
        assert len(collars.odom[agent]) == offline.meta['counters'][agent]['accepted']
        reported = collars.last_status(agent)[2]
        for reason, count in offline.meta['counters'][agent].items():
            assert int(reported[reason]) == count, (agent, reason)


@pytest.mark.parametrize('overrides, message', [
    ([], 'agents must be a non-empty list'),
    (['agents:=[cow_a, 2cow]'], "agent id '2cow' is not a valid ROS name"),
    (['agents:=[cow_a]', 'dt:=0.0'], 'dt must be within [0.001, 1e+06], got 0.0'),
    (['agents:=[cow_a]', 'executor:=fast'], 'executor must be one of events, single_threaded'),
    (['agents:=[cow_a]', 'datum:=[46.8]'], 'datum must be []'),
    (['agents:=[cow_a]', 'fix_topic:=herd fix'], "fix_topic must be empty or a topic name, "
                                                 "got 'herd fix'"),
])
def test_bad_parameters_stop_with_one_clear_line(ros_env, console_script, overrides, message):
    args = [console_script('gps_ingest'), '--ros-args']
    for o in overrides:
        args += ['-p', o]
    proc = subprocess.Popen(args, env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        _, err = proc.communicate(timeout=30)
    finally:
        stop(proc)
    assert proc.returncode == 2
    assert message in err


@pytest.mark.slow
def test_node_on_collars_with_every_real_fault(ros, console_script, tmp_path):
    """Issue 10, acceptance 1 for the node: three days of a realistic herd through collars with
    every real-collar fault (duty cycle 30-250 s, silences of hours, late start, early end,
    outlier bursts, duplicated stamps). The node publishes the offline path's snapshots —
    so what test_real_collar_faults.py shows of those holds for the node — and no pose it
    publishes sits on a burst or extrapolates a silent collar."""
    from herd_ros.synthesis.collar_errors import CollarErrorModel, simulate_collar_fixes
    from herd_ros.synthesis.cow_scenario import simulate_cow_herd
    node, env = ros
    truth = simulate_cow_herd(n_cows=3, duration_s=2 * 86400.0, dt=10.0, seed=5)
    model = CollarErrorModel.real_collar(silence_rate=1.0 / 86400.0)
    fixes = simulate_collar_fixes(truth, seed=5, model=model)
    datum = fixes.attrs['datum']
    agents = list(truth.agents)
    var = fixes['cov_ee'].fillna(0.0).to_numpy()
    rows = [(a, float(t), float(la), float(lo), float(al), int(st), int(ct), float(v))
            for a, t, la, lo, al, st, ct, v in zip(
                fixes['agent'], fixes['time'], fixes['lat'], fixes['lon'], fixes['alt'],
                fixes['status'], fixes['position_covariance_type'], var)]
    table = pd.DataFrame(rows, columns=['agent', 'time', 'lat', 'lon', 'alt', 'status',
                                        'position_covariance_type', 'cov_ee'])
    table['cov_nn'] = table['cov_ee']
    table['cov_en'] = 0.0
    offline = trajectory_from_fixes(table, datum=datum, trim=False, agents=agents)
    fp = offline.meta['filter_params']
    params = dict(dt=offline.meta['dt'], stale_after=fp.stale_after,
                  reinit_after_gap=fp.reinit_after_gap, datum=list(datum),
                  fix_queue_depth=1000)

    collars = Collars(node, agents)
    proc = start_node(console_script, env, tmp_path, agents, **params)
    try:
        collars.wait_for_node(proc)
        collars.publish(rows)
        sent = {a: sum(r[0] == a for r in rows) for a in agents}
        collars.spin(30.0, lambda: all(collars.counted(a) == sent[a] for a in agents))
        assert {a: collars.counted(a) for a in agents} == sent, 'fixes were lost'
    finally:
        rc = stop(proc)
    assert rc == 0
    index = {round(t, 6): k for k, t in enumerate(offline.times)}
    compared = stale_nan = 0
    for m in collars.poses:
        k = index[round(stamp_to_seconds(m.header.stamp), 6)]
        node_xy = np.array([[p.position.x, p.position.y] for p in m.poses])
        np.testing.assert_allclose(node_xy, offline.positions[k], atol=1e-6, rtol=0,
                                   equal_nan=True)
        stale_nan += int(np.isnan(node_xy[offline.meta['stale'][k], 0]).sum())
        compared += 1
    assert compared > 0.9 * len(offline.times)
    assert stale_nan == offline.meta['stale'][[index[round(stamp_to_seconds(m.header.stamp), 6)]
                                               for m in collars.poses]].sum() > 0
    burst = fixes['burst'].to_numpy()
    assert burst.sum() > 5
    assert not np.isin(offline.meta['fix_outcomes'][burst], ['accepted', 'reinitialised']).any()


def test_a_large_herd_is_reported_in_turn(ros, console_script, tmp_path):
    """diagnostics_max_collars: at most that many collar statuses per period, every collar
    reported in turn, the node's totals every period."""
    node, env = ros
    agents = [f'cow_{k}' for k in range(5)]
    proc = start_node(console_script, env, tmp_path, agents, diagnostics_max_collars=2,
                      datum=[46.8, 7.15, 550.0])
    arrays = []
    node.create_subscription(DiagnosticArray, '/diagnostics', arrays.append, 50)
    executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and len(arrays) < 6:
            executor.spin_once(timeout_sec=0.1)
    finally:
        assert stop(proc) == 0, proc.log_path.read_text()
    assert len(arrays) >= 6, 'too few diagnostics'
    seen = set()
    for msg in arrays:
        collars = [s for s in msg.status if s.hardware_id]
        assert len(collars) <= 2
        seen |= {s.hardware_id for s in collars}
        summary = [s for s in msg.status if s.name == 'gps_ingest']
        assert len(summary) == 1 and 'in turn' in summary[0].message
        keys = {kv.key for kv in summary[0].values}
        assert {'fixes', 'accepted', 'stale_collars'} <= keys
    assert seen == set(agents)
