"""The whole herd graph in one process (what ``herd-ros demo`` runs on the pip path).

replay → gps_ingest → estimator → controller → fleet_sim, composed on one executor: the
same nodes and topics as ``launch/herd.launch.py``. Every node reads its own section of one
parameters file (the ROS way: ``--ros-args --params-file``), and all but the replay follow
the bag's ``/clock`` (``use_sim_time``), so the robots live in the cows' time while the bag
plays faster than real time.

Nothing in it is specific to one herd: the datum, the herd clock, the field, the fence, the
robots' start and speed and the replay rate come from the bag
(:func:`herd_ros.herd_setup.herd_setup_from_fixes`).

A small recorder node keeps what the report needs: the herd snapshots (``/herd/poses``), the
estimator's one-step predictions as published (``/herd/model/prediction``), the robots'
poses with their own stamps (``/fleet/poses``, matched to the herd ticks by time afterwards:
:func:`robots_at`) and the learned parameters over time (``/herd/model/params``).
"""
from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import numpy as np

def robots_at(times, fleet_times, fleet_xy, interpolate: bool = False) -> np.ndarray:
    """The robots' positions (T, R, 2) at herd ticks ``times``, from fleet snapshots
    ``fleet_xy`` (F, R, 2) stamped ``fleet_times`` (F,): the last fleet snapshot
    stamped at or before each tick (NaN before the first, and more than two fleet steps after
    a snapshot: the fleet had not got there). By stamp, not by arrival: with the
    bag played hundreds of times faster than real time, the fleet's poses reach the recorder
    in bursts, and the latest one received at a herd tick can be minutes of herd time off
    (robots seemed to jump 100 m in 30 s). ``interpolate``: linearly between that snapshot
    and the next where the next is within two fleet steps (times between the snapshots:
    an animal's fix stamps)."""
    times = np.asarray(times, dtype=float)
    ft = np.asarray(fleet_times, dtype=float)
    xy = np.asarray(fleet_xy, dtype=float)              # (F, R, 2)
    if not len(ft):
        return np.full((len(times),) + xy.shape[1:], np.nan)
    order = np.argsort(ft, kind='stable')
    ft, xy = ft[order], xy[order]
    k = np.searchsorted(ft, times + 1e-9, side='right') - 1
    out = np.full((len(times),) + xy.shape[1:], np.nan)
    steps = np.diff(np.unique(ft))
    reach = 2.0 * float(np.median(steps)) if len(steps) else np.inf
    ok = (k >= 0) & (times - ft[np.maximum(k, 0)] <= reach + 1e-9)
    out[ok] = xy[k[ok]]
    if interpolate:
        nxt = np.minimum(k + 1, len(ft) - 1)
        between = ok & (nxt > k) & (ft[nxt] - ft[np.maximum(k, 0)] <= reach + 1e-9)
        kb, nb = k[between], nxt[between]
        w = ((times[between] - ft[kb]) / (ft[nb] - ft[kb]))[:, None, None]
        out[between] = (1.0 - w) * xy[kb] + w * xy[nb]
    return out


class DemoRecorder:
    """Records herd snapshots, the robots' stamped poses and parameters over time."""

    def __init__(self, node, n_robots: int, agents=()):
        from geometry_msgs.msg import PoseArray
        from nav_msgs.msg import Odometry
        from std_msgs.msg import Float64MultiArray
        self.node = node
        self.lock = threading.Lock()
        self.herd_times, self.herd = [], []
        self.fleet_times, self.fleet = [], []
        self.param_times, self.params = [], []
        self.pred_times, self.preds = [], []
        self.n_robots = int(n_robots)
        self.robots_moved = False
        node.create_subscription(PoseArray, '/herd/poses', self.on_herd, 1000)
        node.create_subscription(PoseArray, '/fleet/poses', self.on_fleet, 1000)
        node.create_subscription(Float64MultiArray, '/herd/model/params', self.on_params, 100)
        node.create_subscription(PoseArray, '/herd/model/prediction', self.on_prediction, 100)
        # each animal's accepted fixes (gps_ingest's odometry, stamped with the fix): when
        # its track was informed, and where the track put the animal then
        self.fix_times = {a: [] for a in agents}
        self.fix_xy = {a: [] for a in agents}
        for a in agents:
            node.create_subscription(Odometry, f'/herd/{a}/odom',
                                     lambda msg, a=a: self.on_fix(a, msg), 1000)
        self.first_fleet = None

    @staticmethod
    def _xy(msg) -> np.ndarray:
        from herd_ros.nodes.ros_common import pose_array_xy
        return pose_array_xy(msg)

    def on_herd(self, msg):
        """Keep a /herd/poses snapshot."""
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        with self.lock:
            self.herd_times.append(t)
            self.herd.append(self._xy(msg))

    def on_fix(self, agent: str, msg):
        """Note the stamp of an accepted fix of ``agent`` and its track's position there."""
        p = msg.pose.pose.position
        with self.lock:
            self.fix_times[agent].append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
            self.fix_xy[agent].append((p.x, p.y))

    def on_prediction(self, msg):
        """Keep one of the estimator's one-step predictions."""
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        with self.lock:
            self.pred_times.append(t)
            self.preds.append(self._xy(msg))

    def on_fleet(self, msg):
        """Keep the robots' positions with their stamp and note when they first move."""
        xy = self._xy(msg)
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        with self.lock:
            if xy.shape == (self.n_robots, 2):
                self.fleet_times.append(t)
                self.fleet.append(xy)
                if self.first_fleet is None:
                    self.first_fleet = xy.copy()
                elif np.nanmax(np.abs(xy - self.first_fleet)) > 0.5:
                    self.robots_moved = True

    def on_params(self, msg):
        """Keep the learned parameters (agent × param) at the latest herd tick."""
        dims = msg.layout.dim
        if len(dims) != 2:
            return
        theta = np.asarray(msg.data, dtype=float)[:dims[0].size * dims[1].size]
        with self.lock:
            t = self.herd_times[-1] if self.herd_times else np.nan
            self.param_times.append(t)
            self.params.append(theta.reshape(dims[0].size, dims[1].size))


def run_live_demo(bag, out_dir, rate: float | None = None, dt: float | None = None,
                  progress_period_s=5.0, log=print, herd_file=None) -> dict:
    """Play ``bag`` through the composed graph; returns the summary written to ``out_dir``.

    The herd comes from ``herd_file`` (:mod:`herd_ros.herd_file`) when given, else from what
    the bag implies (:mod:`herd_ros.herd_setup`; ``rate`` and ``dt`` override); either way
    it is written to ``out_dir/herd.yaml``, which ``ros2 launch herd_ros herd.launch.py
    herd:=...`` runs as the same graph."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from herd_ros.herd_file import (dump_yaml, node_parameters, read_herd_file,
                                    write_herd_file)
    from herd_ros.herd_setup import LIVE_MIN_DT, herd_setup_from_fixes
    from herd_ros.io.bags import bag_info, read_fix_bag
    from herd_ros.nodes.controller import Controller
    from herd_ros.nodes.estimator import Estimator
    from herd_ros.nodes.fleet_sim import FleetSim
    from herd_ros.nodes.gps_ingest import GpsIngest
    from herd_ros.nodes.replay import Replay
    from herd_ros.report.demo_report import seen_at_fixes, write_demo_report
    from herd_ros.trajectory import HerdTrajectory

    # absolute: the nodes resolve a relative model/checkpoint path under their data
    # directory ($ROS_HOME/herd_ros), not here (a second `make demo` then resumed the first
    # run's checkpoint, its clock ahead of the replay, and learned nothing)
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    info = bag_info(bag)
    if herd_file is not None:
        setup, _ = read_herd_file(herd_file)
        if rate is not None:
            setup.rate = float(rate)
        setup.duration_s = float(info.duration_s)
        log(f'herd from {herd_file}:\n{setup.describe()}')
    else:
        setup = herd_setup_from_fixes(read_fix_bag(bag), dt=dt, rate=rate,
                                      min_dt=LIVE_MIN_DT)
        log(f'chosen from the bag {Path(bag).name}:\n{setup.describe()}')
    rate = setup.rate
    agents, robots = setup.agents, setup.robots
    fence = np.asarray(setup.fence, dtype=float)
    write_herd_file(out / 'herd.yaml', setup, bag, header=(
        f'Herd file of the demo run on {Path(bag).name} (herd-ros demo).\n'
        f'The same graph on a ROS install: ros2 launch herd_ros herd.launch.py '
        f'herd:={(out / "herd.yaml").resolve()}'))
    params = node_parameters(setup, bag, out_dir=out, rate=rate, composed=True)
    # a demo starts afresh: an estimator checkpoint left by an earlier run in this folder
    # would be resumed (and its clock would be ahead of the replay)
    (out / 'estimator_checkpoint.npz').unlink(missing_ok=True)
    params_file = out / 'demo_parameters.yaml'
    params_file.write_text(dump_yaml(params))
    log(f'graph: replay({Path(bag).name}, rate {rate:g}) -> gps_ingest -> estimator -> '
        f'controller -> fleet_sim; {len(agents)} animals, {len(robots)} robots; '
        f'parameters: {params_file}; herd file: {out / "herd.yaml"}')

    rclpy.init(args=['--ros-args', '--params-file', str(params_file)])
    nodes, spinner = [], None
    # One single-threaded executor for the whole graph. The graph runs in data time, so
    # every topic's messages must be handled in order; rclpy's MultiThreadedExecutor does not
    # keep a subscription's messages in order, and a second executor thread starves the data
    # path of the GIL until fixes drop (both measured: the herd snapshots then differ from the
    # offline ingest of the same bag; with one executor they are identical).
    executor = SingleThreadedExecutor()
    stopping = threading.Event()
    t0 = time.monotonic()
    try:
        from rclpy.node import Node
        recorder_node = Node('demo_recorder', parameter_overrides=[rclpy.parameter.Parameter(
                                 'use_sim_time', rclpy.parameter.Parameter.Type.BOOL, True)])
        recorder = DemoRecorder(recorder_node, len(robots), agents)
        nodes.append(recorder_node)
        for cls in (FleetSim, Controller, Estimator, GpsIngest, Replay):
            nodes.append(cls())
        replay = nodes[-1]
        for n in nodes:
            executor.add_node(n)
        spinner = threading.Thread(target=_spin, args=(executor, stopping), daemon=True)
        spinner.start()
        next_report = time.monotonic() + progress_period_s
        while spinner.is_alive() and not replay.finished.is_set():
            spinner.join(timeout=0.2)
            if time.monotonic() >= next_report:
                next_report += progress_period_s
                with recorder.lock:
                    done = ((recorder.herd_times[-1] - info.start_ns * 1e-9) / info.duration_s
                            if recorder.herd_times else 0.0)
                    log(f'  {time.monotonic() - t0:5.0f} s: bag {100 * done:3.0f} %, '
                        f'{len(recorder.herd_times)} herd snapshots, {len(recorder.params)} '
                        f'model updates, robots {"moving" if recorder.robots_moved else "waiting"}')
        # let the graph work off what the replay sent (it may lag behind a busy core): wait
        # until no new snapshot has arrived for a second (at most 30 s)
        last, quiet_since, deadline = -1, time.monotonic(), time.monotonic() + 30.0
        while time.monotonic() < deadline and time.monotonic() - quiet_since < 1.0:
            time.sleep(0.2)
            with recorder.lock:
                count = len(recorder.herd_times)
            if count != last:
                last, quiet_since = count, time.monotonic()
    except ExternalShutdownException:
        pass
    finally:
        estimator = next((n for n in nodes if isinstance(n, Estimator)), None)
        controller = next((n for n in nodes if isinstance(n, Controller)), None)
        stop_graph(executor, spinner, nodes, stopping)
        rclpy.try_shutdown()
    model_path = out / 'learned_model.yaml'
    live_skill = None
    if estimator is not None:
        estimator.core.save_model(model_path, datum=list(setup.datum) or None)
        sk = estimator.core.skill()
        live_skill = {
            'method': 'prequential: each one-step prediction made before its update, '
                      'running RMS (m) over the whole run',
            'herd': {m: sk[f'{m}_herd'] for m in ('model', 'constant_velocity', 'stay_put')},
            'agents': {a: {m: float(sk[m][i]) for m in ('model', 'constant_velocity',
                                                         'stay_put')}
                       for i, a in enumerate(agents)},
            'predictions': int(sk['predictions'].sum())}
    with recorder.lock:
        times = np.asarray(recorder.herd_times)
        cows = HerdTrajectory(times, agents, np.asarray(recorder.herd).reshape(-1, len(agents), 2))
        fleet_times = np.asarray(recorder.fleet_times)
        fleet_xy = np.asarray(recorder.fleet).reshape(-1, len(robots), 2)
        rob = robots_at(times, fleet_times, fleet_xy)
        param_times, thetas = list(recorder.param_times), list(recorder.params)
        pred_times = np.asarray(recorder.pred_times)
        preds = np.asarray(recorder.preds).reshape(-1, len(agents), 2)
        # each animal and its robot where the animal's track was informed: at its fixes
        animal_fixes = [last_per_stamp(recorder.fix_times[a], recorder.fix_xy[a])
                        for a in agents]
        fix_times, fix_xy = [], []
        for k, (ft, _) in enumerate(animal_fixes[:len(robots)]):  # robot k follows animal k
            fix_times.append(ft)
            fix_xy.append(robots_at(ft, fleet_times, fleet_xy, interpolate=True)[:, k]
                          if len(ft) else np.zeros((0, 2)))
    cows_at_fixes = HerdTrajectory(times, agents, np.where(
        np.isfinite(cows.positions),
        seen_at_fixes(times, [ft for ft, _ in animal_fixes], [xy for _, xy in animal_fixes]),
        np.nan))
    active = np.isfinite(rob).all(axis=(1, 2))
    if len(thetas):
        first_model_t = param_times[0]
        active &= times > first_model_t
    # each robot and its animal from the tick the robot's law took over (before it, the
    # robot waited: it escorted its animal or held still, control/escort.py)
    law_since = getattr(getattr(controller, 'policy', None), 'law_since', None)
    robot_fixes = seen_at_fixes(times, fix_times, fix_xy)
    if law_since is not None and len(law_since) == len(robots):
        before = ~(times[:, None] >= law_since[None, :])         # (T, R); NaN: never
        rob[before] = np.nan
        robot_fixes[before] = np.nan
        active &= ~before.all(axis=1)
        n = min(len(robots), len(agents))                       # robot k follows animal k
        scored = np.array(cows.positions, dtype=float)
        for animals in (cows_at_fixes.positions, scored):
            animals[:, :n][before[:, :n]] = np.nan
        cows_scored = HerdTrajectory(times, agents, scored)
        facts_law = {r: (float(v) if np.isfinite(v) else None)
                     for r, v in zip(robots, law_since)}
    else:
        facts_law, cows_scored = None, cows
    robots_traj = HerdTrajectory(times[active], robots, rob[active])
    at_fixes = HerdTrajectory(times[active], robots, robot_fixes[active])
    from herd_ros.trajectory import write_trajectory_csv
    predictions = HerdTrajectory(pred_times, agents, preds)
    write_trajectory_csv(out / 'herd_poses.csv', cows)
    write_trajectory_csv(out / 'herd_predictions.csv', predictions)
    write_trajectory_csv(out / 'robots_fleet_poses.csv', robots_traj)
    from herd_ros.simulation.prediction import published_prediction_skill
    skill = published_prediction_skill(cows, predictions, setup.dt, clock=setup.clock)
    facts = {'bag': str(bag), 'datum': list(setup.datum), 'dt': setup.dt,
             'herd_clock_s': setup.clock, 'rate': rate,
             'setup': setup.to_dict(), 'wall_time_s': time.monotonic() - t0,
             'herd_snapshots': int(len(times)), 'model_updates': int(len(thetas)),
             'robot_samples': int(active.sum()), 'model_file': str(model_path),
             'prediction_skill': skill, 'estimator_skill': live_skill}
    if facts_law is not None:
        # the moment (bag time, s) each robot's law took over; scored from there
        facts['law_since'] = facts_law
        facts['bag_start_s'] = info.start_ns * 1e-9
    pace = getattr(getattr(controller, 'policy', None), 'pace', None)
    if pace is not None:
        # each robot's factor on its noise, matched to its animal's speed (pace_match)
        facts['pace_factors'] = {r: float(f) for r, f in zip(robots, pace.factors)}
        facts['pace_factor_history'] = [{'time': float(t), 'factors': [float(v) for v in f]}
                                        for t, f in pace.history]
    place = getattr(getattr(controller, 'policy', None), 'place_match', None)
    if place is not None:
        # each robot's share of its place pull inside its range (place_match)
        facts['place_shares'] = {r: float(v) for r, v in zip(robots, place.shares)}
        facts['place_share_history'] = [{'time': float(t), 'shares': [float(v) for v in f]}
                                        for t, f in place.history]
    profile_size = int(params['estimator']['ros__parameters'].get('profile_size', 6))
    return write_demo_report(out, cows_scored, robots_traj, agents, param_times, thetas, fence,
                             facts, law=setup.law, profile_size=profile_size,
                             robots_at_fixes=at_fixes, cows_at_fixes=cows_at_fixes)


def last_per_stamp(stamps, positions) -> tuple[np.ndarray, np.ndarray]:
    """(stamps (F,), positions (F, 2)) sorted by stamp, one per stamp (the last received:
    a fix published again after a correction replaces the first)."""
    t = np.asarray(stamps, dtype=float)
    xy = np.asarray(positions, dtype=float).reshape(-1, 2)
    order = np.argsort(t, kind='stable')
    t, xy = t[order], xy[order]
    last = np.append(t[1:] != t[:-1], True) if len(t) else np.zeros(0, dtype=bool)
    return t[last], xy[last]


def stop_graph(executor, spinner, nodes, stopping):
    """End the run: stop the spin, wait for its thread, then each node's ``on_shutdown``
    (the ingest publishes the fixes still waiting, the estimator saves), then destroy them.

    The spin stops first: a hook run while the spin thread is still inside a callback of the
    same node races it (the ingest's diagnostics generator was once advanced from both
    threads at once, "generator already executing", and the demo died at its last step)."""
    stopping.set()
    executor.shutdown(timeout_sec=10.0)
    if spinner is not None:
        # destroying the nodes under a spin that has not returned yet raises in it
        spinner.join(timeout=10.0)
    for n in nodes:
        hook = getattr(n, 'on_shutdown', None)
        if hook is not None:
            hook()
    for n in nodes:
        n.destroy_node()


def _spin(executor, stopping=None):
    """Spin until shutdown. Once ``stopping`` is set the nodes are being destroyed, and on a
    saturated machine the spin may not have returned yet (the join has a timeout): a
    handle destroyed under it is then the end of the run, not an error."""
    from rclpy.executors import ExternalShutdownException
    try:
        executor.spin()
    except (ExternalShutdownException, KeyboardInterrupt):
        pass
    except Exception:
        if stopping is None or not stopping.is_set():
            raise
