"""`herd-ros demo --herding`: the herding graph live, in one process (issue 27).

herd_sim (Strömbom's sheep fleeing the robots, driving ``/clock``) → controller (mode
``herding``, Strömbom's shepherd) → fleet_sim (the herders), composed on one executor: the
same nodes and parameters as ``launch/herding.launch.py``
(:func:`herd_ros.herding.live_graph.herding_parameters`). A recorder keeps ``/herd/poses``
and ``/fleet/poses``; the run ends when every animal is inside the goal circle, or when
the benchmark's budget (1500 + 30 N simulated seconds) is spent.

Writes ``DIR/herding_herd.csv`` and ``DIR/herding_robots.csv`` (trajectory CSVs),
``DIR/herding.png`` (the paths, the goal) and ``DIR/summary.json`` (success, simulated time,
the herd's final distance from the goal, wall time).
"""
from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np


class HerdingRecorder:
    """Records the animals (``/herd/poses``) with the robots' latest positions, and counts
    the controller's ``/herding/markers``."""

    def __init__(self, node, n_robots: int):
        from geometry_msgs.msg import PoseArray

        from herd_ros.nodes.ros_common import pose_array_xy
        self._xy = pose_array_xy
        self.lock = threading.Lock()
        self.times, self.herd, self.robots = [], [], []
        self.latest = np.full((n_robots, 2), np.nan)
        self.markers = 0
        node.create_subscription(PoseArray, '/herd/poses', self.on_herd, 100)
        node.create_subscription(PoseArray, '/fleet/poses', self.on_fleet, 100)
        from visualization_msgs.msg import MarkerArray
        node.create_subscription(MarkerArray, '/herding/markers', self.on_markers, 10)

    def on_markers(self, msg):
        """Count one /herding/markers message."""
        with self.lock:
            self.markers += 1

    def on_herd(self, msg):
        """Keep a /herd/poses snapshot with the robots' latest positions."""
        with self.lock:
            self.times.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
            self.herd.append(self._xy(msg))
            self.robots.append(self.latest.copy())

    def on_fleet(self, msg):
        """Keep the robots' latest positions from /fleet/poses."""
        xy = self._xy(msg)
        with self.lock:
            if xy.shape == self.latest.shape:
                self.latest = xy


def run_herding_demo(out_dir, n_animals: int = 14, herders: int = 1, rate: float = 20.0,
                     seed: int = 0, log=print, progress_period_s: float = 5.0,
                     herder: str = 'strombom', model_warmup: str = 'strombom') -> dict:
    """Run the herding graph until the herd is home or the budget is spent; returns the
    summary written to ``out_dir/summary.json``."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from herd_ros.herd_file import dump_yaml
    from herd_ros.herding.benchmark import GOAL, GOAL_RADIUS
    from herd_ros.herding.live_graph import budget_s, herding_parameters, robot_names
    from herd_ros.herding.strombom import herd_in_goal
    from herd_ros.nodes.controller import Controller
    from herd_ros.nodes.fleet_sim import FleetSim
    from herd_ros.nodes.herd_sim import HerdSim, animal_names
    from herd_ros.cli.live_demo import _spin
    from herd_ros.trajectory import HerdTrajectory, write_trajectory_csv

    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    params = herding_parameters(n_animals, herders, rate, seed, herder=herder,
                                model_warmup=model_warmup)
    params_file = out / 'herding_parameters.yaml'
    params_file.write_text(dump_yaml(params))
    budget = budget_s(n_animals)
    robots, animals = robot_names(herders), animal_names(n_animals)
    log(f'graph: herd_sim ({n_animals} animals, driving /clock at {rate:g}x) -> controller '
        f'(mode herding, {herder}, {herders} herder{"s" * (herders > 1)}) -> fleet_sim; '
        f'goal {list(GOAL)} '
        f'radius {GOAL_RADIUS:g} m; budget {budget:.0f} s simulated; parameters: '
        f'{params_file}')
    rclpy.init(args=['--ros-args', '--params-file', str(params_file)])
    executor = SingleThreadedExecutor()
    nodes, spinner = [], None
    t0 = time.monotonic()
    home_at = None
    try:
        rec_node = Node('herding_recorder', parameter_overrides=[
            Parameter('use_sim_time', Parameter.Type.BOOL, True)])
        recorder = HerdingRecorder(rec_node, herders)
        nodes = [rec_node, FleetSim(), Controller(), HerdSim()]
        for n in nodes:
            executor.add_node(n)
        spinner = threading.Thread(target=_spin, args=(executor,), daemon=True)
        spinner.start()
        next_report = time.monotonic() + progress_period_s
        while spinner.is_alive():
            time.sleep(0.1)
            with recorder.lock:
                t = recorder.times[-1] if recorder.times else 0.0
                P = recorder.herd[-1] if recorder.herd else None
            if P is not None and home_at is None and herd_in_goal(P[None], GOAL,
                                                                  GOAL_RADIUS)[0]:
                home_at = t
                log(f'  {time.monotonic() - t0:5.0f} s: the herd is inside the goal at '
                    f'{t:.0f} s simulated')
            if home_at is not None and t >= home_at + 5.0:       # a few seconds at home
                break
            if t >= budget:
                log(f'  budget of {budget:.0f} s simulated spent')
                break
            if time.monotonic() >= next_report:
                next_report += progress_period_s
                if P is not None:
                    d = np.sqrt(((P - np.asarray(GOAL)) ** 2).sum(-1))
                    log(f'  {time.monotonic() - t0:5.0f} s: {t:5.0f} s simulated, herd centre '
                        f'{np.hypot(*(P.mean(axis=0) - GOAL)):.0f} m from the goal, '
                        f'{int((d <= GOAL_RADIUS).sum())} of {len(P)} inside')
    finally:
        executor.shutdown(timeout_sec=2.0)
        if spinner is not None:
            spinner.join(timeout=10.0)
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
    with recorder.lock:
        times = np.asarray(recorder.times)
        herd = np.asarray(recorder.herd).reshape(-1, n_animals, 2)
        rob = np.asarray(recorder.robots).reshape(-1, herders, 2)
        markers = recorder.markers
    write_trajectory_csv(out / 'herding_herd.csv', HerdTrajectory(times, animals, herd))
    write_trajectory_csv(out / 'herding_robots.csv', HerdTrajectory(times, robots, rob))
    final = herd[-1] if len(herd) else np.full((n_animals, 2), np.nan)
    dist = np.sqrt(((final - np.asarray(GOAL)) ** 2).sum(-1))
    summary = {
        'success': bool(home_at is not None), 'time_s': home_at, 'budget_s': budget,
        'n_animals': n_animals, 'herders': herders, 'goal': list(GOAL),
        'goal_radius': GOAL_RADIUS, 'final_inside': int((dist <= GOAL_RADIUS).sum()),
        'final_max_distance_m': float(np.nanmax(dist)), 'snapshots': int(len(times)),
        'marker_messages': int(markers),
        'rate': rate, 'seed': seed, 'wall_time_s': time.monotonic() - t0,
        'herder': herder, 'files': ['herding_herd.csv', 'herding_robots.csv',
                                        'herding.png', 'herding_parameters.yaml']}
    (out / 'summary.json').write_text(json.dumps(summary, indent=2))
    _figure(out / 'herding.png', herd, rob, GOAL, GOAL_RADIUS, summary)
    return summary


def _figure(path, herd, robots, goal, radius, summary):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.add_patch(plt.Circle(goal, radius, color='tab:green', alpha=0.25, label='goal'))
    for i in range(herd.shape[1]):
        ax.plot(herd[:, i, 0], herd[:, i, 1], color='tab:orange', lw=0.5, alpha=0.6,
                label='animals' if i == 0 else None)
    for k in range(robots.shape[1]):
        ax.plot(robots[:, k, 0], robots[:, k, 1], color='tab:blue', lw=1.0,
                label='herders' if k == 0 else None)
    if len(herd):
        ax.scatter(herd[-1, :, 0], herd[-1, :, 1], s=12, color='tab:orange', zorder=3)
    ax.set_aspect('equal')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    verdict = (f"home after {summary['time_s']:.0f} s" if summary['success']
               else f"not home within {summary['budget_s']:.0f} s")
    ax.set_title(f"herding, live graph: {summary['n_animals']} animals, "
                 f"{summary['herders']} herder(s), {verdict}")
    ax.legend(loc='upper left')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
