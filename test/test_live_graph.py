"""The whole graph as separate processes (issue: robots that move like the herd, acceptance 1).

replay (the shipped cow bag, /clock) → gps_ingest → estimator → controller → fleet_sim, each
an installed console script with loopback-only discovery, all reading their sections of one
parameters file (the one `herd-ros demo` composes in a single process). A sixth process,
`record`, writes /herd/poses, /fleet/poses and /herd/model/params to a bag, which the test
reads back with rosbags. Expectations are independent of the code under test: the robots'
herd statistics are compared with the cows' as they come out of ingest (same clock, same
statistics, each robot and its animal from the moment the robot's law took over, which the
controller's /diagnostics give, as the demo scores them), parameters must settle, robots
must move and stay inside the fence.
"""
import signal
import subprocess
import time

import numpy as np
import pytest
from matplotlib.path import Path as PolyPath

from conftest import REPO
from herd_ros.herd_setup import herd_setup_from_fixes
from herd_ros.io.bags import read_fix_bag, read_messages
from herd_ros.herd_file import dump_yaml, node_parameters
from herd_ros.simulation.statistics import STATISTICS, herd_statistics
from herd_ros.trajectory import HerdTrajectory

BAG = REPO / 'bags' / 'cows_3x1h'
AGENTS = ['cow_1', 'cow_2', 'cow_3']
ROBOTS = ['robot_1', 'robot_2', 'robot_3']
DT = 20.0
RATE = 60.0


def _stop(procs):
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    deadline = time.monotonic() + 10
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _poses(msg):
    return np.array([[p.position.x, p.position.y] for p in msg.poses], dtype=float)


@pytest.mark.slow
def test_robots_learn_from_replayed_cows_and_move_like_them(tmp_path, ros_env, console_script):
    setup = herd_setup_from_fixes(read_fix_bag(BAG), dt=DT, rate=RATE)
    assert setup.agents == AGENTS and setup.robots == ROBOTS
    fence = np.asarray(setup.fence)
    params = node_parameters(setup, BAG, out_dir=tmp_path, rate=RATE)
    params['replay']['ros__parameters']['exit_when_done'] = True
    params['replay']['ros__parameters']['wait_for_subscribers'] = 1
    params['gps_ingest']['ros__parameters']['fix_queue_depth'] = 1000
    # the controller's default wait: each robot escorts its animal until its law takes
    # over, so the law starts where the animal is (the demo's way)
    params['record'] = {'ros__parameters': {
        'bag': str(tmp_path / 'graph_bag'),
        'topics': ['/herd/poses', '/fleet/poses', '/herd/model/params', '/diagnostics']}}
    params_file = tmp_path / 'graph.yaml'
    params_file.write_text(dump_yaml(params))
    args = ['--ros-args', '--params-file', str(params_file)]
    logs = {}
    procs = []
    try:
        for name in ('record', 'fleet_sim', 'controller', 'estimator', 'gps_ingest'):
            logs[name] = open(tmp_path / f'{name}.log', 'w')
            procs.append(subprocess.Popen([console_script(name), *args], env=ros_env,
                                          stdout=logs[name], stderr=subprocess.STDOUT))
        time.sleep(3.0)   # discovery before the bag starts
        logs['replay'] = open(tmp_path / 'replay.log', 'w')
        replay = subprocess.Popen([console_script('replay'), *args], env=ros_env,
                                  stdout=logs['replay'], stderr=subprocess.STDOUT)
        procs.append(replay)
        assert replay.wait(timeout=400) == 0, (tmp_path / 'replay.log').read_text()[-2000:]
        time.sleep(2.0)
        for p, name in zip(procs[:-1], logs):
            assert p.poll() is None, f'{name} died: ' + (tmp_path / f'{name}.log').read_text()[
                -2000:]
    finally:
        _stop(procs)
        for f in logs.values():
            f.close()

    herd_t, herd_p, fleet_t, fleet_p, dampings = [], [], [], [], []
    law_since = {}
    for topic, _, _, msg in read_messages(tmp_path / 'graph_bag'):
        if topic == '/diagnostics':
            for st in msg.status:
                if st.name.startswith('controller: '):
                    law_since.update({st.hardware_id: float(kv.value) for kv in st.values
                                      if kv.key == 'law_since'})
            continue
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec \
            if hasattr(msg, 'header') else None
        if topic == '/herd/poses':
            herd_t.append(stamp)
            herd_p.append(_poses(msg))
        elif topic == '/fleet/poses':
            fleet_t.append(stamp)
            fleet_p.append(_poses(msg))
        else:
            n, p = msg.layout.dim[0].size, msg.layout.dim[1].size
            dampings.append(np.asarray(msg.data)[:n * p].reshape(n, p)[:, 0])
    herd_t, herd_p = np.array(herd_t), np.array(herd_p)
    fleet_t, fleet_p = np.array(fleet_t), np.array(fleet_p)
    order = np.argsort(herd_t)
    herd_t, herd_p = herd_t[order], herd_p[order]
    assert len(herd_t) > 0.9 * 3600 / DT and np.allclose(np.diff(herd_t), DT)

    # parameters converge: the damping estimates settle over the last half of the hour
    d = np.array(dampings)
    assert len(d) > 0.9 * 3600 / DT and np.isfinite(d).all()
    half = d[len(d) // 2:]
    assert (half.max(0) - half.min(0) < 0.25).all(), half.max(0) - half.min(0)
    assert (np.abs(d[-1]) < 1).all()

    # robots at the herd ticks (last fleet pose at or before each tick)
    order = np.argsort(fleet_t)
    fleet_t, fleet_p = fleet_t[order], fleet_p[order]
    idx = np.searchsorted(fleet_t, herd_t, side='right') - 1
    ok = idx >= 0
    times, robots, cows_p = herd_t[ok], fleet_p[idx[ok]], herd_p[ok]
    moved = np.linalg.norm(robots - robots[0], axis=-1).max(0)
    assert (moved > 5.0).all(), f'robots hardly moved: {moved}'
    inside = PolyPath(np.vstack([fence, fence[:1]])).contains_points(fleet_p.reshape(-1, 2))
    assert inside.all(), 'a robot left the fence'
    # each robot, and its animal, from the moment its law took over (the controller's
    # /diagnostics), as the demo scores them: before it the robot waited
    assert sorted(law_since) == ROBOTS and np.isfinite(list(law_since.values())).all(), \
        law_since
    since = np.array([law_since[r] for r in ROBOTS])
    assert (since < times[-1] - 0.5 * 3600).all(), since - times[0]   # the law ran ≥ ½ h
    before = times[:, None] < since[None, :]
    robots[before], cows_p[before] = np.nan, np.nan     # both copies (fancy indexing)
    cows = herd_statistics(HerdTrajectory(times, AGENTS, cows_p))
    bots = herd_statistics(HerdTrajectory(times, ROBOTS, robots))
    table = {key: (np.mean([cows[a][key] for a in AGENTS]),
                   np.mean([bots[b][key] for b in ROBOTS])) for key in STATISTICS}
    print('herd statistics (cows, robots):', {k: (round(c, 3), round(r, 3))
                                               for k, (c, r) in table.items()},
          'law since (s after the first tick):', np.round(since - times[0]))
    for key, (c, r) in table.items():
        assert abs(r - c) <= 0.30 * c, (key, table)
