"""`herd_sim` node: simulated animals that flee the robots, for herding (issue 27).

The animals are Strömbom et al.'s (2014) sheep (:func:`herd_ros.herding.strombom
.sheep_step`: inertia, cohesion to the local centre of their n nearest neighbours,
repulsion from crowding, flight from every robot within ``flight_distance``, noise, grazing
steps). Every robot of ``robots_topic`` (``/fleet/poses``, fleet_sim's) is a dog to them.
Publishes ``/herd/poses`` (PoseArray, ``sheep_1`` .. ``sheep_N`` in order, stamped with the
step's time) after every step, and ``/diagnostics`` (herd centre, spread, alarmed animals).

With ``publish_clock`` the node drives simulated time: a wall-clock timer advances it by
``clock_step_s`` per tick, ``rate`` times faster than real time, publishes ``/clock`` and
steps the animals each ``step_s`` of it; the rest of the graph runs with
``use_sim_time: true`` (``launch/herding.launch.py``, ``herd-ros demo --herding``). The
clock waits while the robots' newest poses lag it by more than ``clock_max_lead_s``, so a
busy machine slows the simulation instead of changing it. Without ``publish_clock`` the
animals step on a timer of the node clock.
"""
from __future__ import annotations

import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseArray
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg

from herd_ros.herding.strombom import SheepParams, sheep_step
from herd_ros.nodes.ros_common import (OK, declare_parameters, describe_remaining_parameters,
                                       diagnostic_array, diagnostic_status, exit_process,
                                       pose_array_xy,
                                       run_node, seconds_to_stamp, stamp_to_seconds,
                                       wall_timer)
from herd_ros.params import ParameterError
from herd_ros.params.herd_sim import PARAMS as DEFAULTS


#: with publish_clock, how long (s of wall time) the clock waits for the robots' first poses
ROBOTS_WAIT_S = 10.0


def animal_names(n: int) -> list[str]:
    """The animals of /herd/poses, in order."""
    return [f'sheep_{k + 1}' for k in range(n)]


class HerdSim(Node):
    """The ``herd_sim`` node (module docstring)."""
    def __init__(self):
        super().__init__('herd_sim')
        p = declare_parameters(self, DEFAULTS)
        centre = np.asarray(list(p['start_center']), dtype=float)
        if centre.shape != (2,) or not np.isfinite(centre).all():
            raise ParameterError(f'start_center must be [x, y], got {list(p["start_center"])}')
        n = int(p['n_animals'])
        self.sheep = SheepParams(n_neighbours=int(p['n_neighbours']) or max(1, n // 2),
                                 r_a=p['spacing'], r_s=p['flight_distance'], e=p['noise'],
                                 delta=p['speed'] * p['step_s'], graze=p['graze'])
        self.agents = animal_names(n)
        self.rng = np.random.default_rng([int(p['seed']), 2014])
        box = p['start_box']
        self.P = (centre + self.rng.uniform(-box / 2, box / 2, size=(n, 2)))[None]
        a = self.rng.uniform(0.0, 2 * np.pi, size=n)
        self.H = np.column_stack([np.cos(a), np.sin(a)])[None]
        self.dogs = np.zeros((1, 0, 2))
        self.robots_time = np.nan          # stamp of the newest /fleet/poses
        self.started = time.monotonic()
        self.waits = 0                     # clock ticks held back for the robots
        self.step_s, self.frame_id = p['step_s'], p['frame_id']
        self.steps = 0
        self.poses_pub = self.create_publisher(PoseArray, '/herd/poses', 10)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(PoseArray, p['robots_topic'], self.on_robots, 10)
        self.diagnostics_period_s = p['diagnostics_period_s']
        self._last_diag = -np.inf
        self.clock_pub = None
        if p['publish_clock']:
            self.clock_pub = self.create_publisher(ClockMsg, '/clock', 10)
            self.sim_time = 0.0
            self.clock_step = p['clock_step_s']
            self.max_lead = p['clock_max_lead_s'] + p['clock_step_s']
            self.next_step = self.step_s
            wall_timer(self, self.clock_step / p['rate'], self.on_clock_tick)
        else:
            self.create_timer(self.step_s, self.on_step_timer)
        describe_remaining_parameters(self, 'not a herd_sim parameter (ignored)')
        self.get_logger().info(
            f'{n} animals (n = {self.sheep.n_neighbours} neighbours, noise {self.sheep.e:g}, '
            f'flight distance {self.sheep.r_s:g} m) about {centre.tolist()}, fleeing the '
            f'robots of {p["robots_topic"]}'
            + (f'; driving /clock at {p["rate"]:g}x real time' if self.clock_pub else ''))
        self.publish_poses(self.now_s())

    def now_s(self) -> float:
        """The simulated time (with publish_clock) or the node clock (s)."""
        if self.clock_pub is not None:
            return self.sim_time
        return self.get_clock().now().nanoseconds * 1e-9

    def on_robots(self, msg: PoseArray):
        """Take the robots' positions (finite ones) as the dogs."""
        self.dogs = pose_array_xy(msg, finite=True)[None]
        self.robots_time = stamp_to_seconds(msg.header.stamp)

    def on_clock_tick(self):
        """Advance simulated time by one clock step, publish /clock, step the animals when
        due; wait while the robots' poses lag by more than ``clock_max_lead_s``."""
        # before the first robot pose, the clock waits at max_lead for up to
        # ROBOTS_WAIT_S of wall time (the robots' simulator needs /clock to start), then runs
        # on alone (a graph without robots)
        behind = (self.sim_time - self.robots_time if np.isfinite(self.robots_time)
                  else self.sim_time if time.monotonic() - self.started < ROBOTS_WAIT_S
                  else -np.inf)
        if behind > self.max_lead + 1e-9:
            self.waits += 1
            return
        self.sim_time += self.clock_step
        msg = ClockMsg()
        msg.clock = seconds_to_stamp(self.sim_time)
        self.clock_pub.publish(msg)
        if self.sim_time + 1e-9 >= self.next_step:
            self.next_step += self.step_s
            self.step()

    def on_step_timer(self):
        """Step the animals (node-clock timer)."""
        self.step()

    def step(self):
        """One step of the sheep; publish their poses (and diagnostics when due)."""
        self.P, self.H = sheep_step(self.P, self.H, self.dogs, self.sheep, self.rng)
        self.steps += 1
        now = self.now_s()
        self.publish_poses(now)
        if now - self._last_diag >= self.diagnostics_period_s - 1e-9:
            self._last_diag = now
            self.publish_diagnostics()

    def publish_poses(self, t: float):
        """Publish the animals on /herd/poses stamped ``t``."""
        msg = PoseArray()
        msg.header.frame_id = self.frame_id
        msg.header.stamp = seconds_to_stamp(t)
        for x, y in self.P[0]:
            pose = Pose()
            pose.position.x, pose.position.y = float(x), float(y)
            pose.orientation.w = 1.0
            msg.poses.append(pose)
        self.poses_pub.publish(msg)

    def publish_diagnostics(self):
        """Publish the herd's centre, spread and alarmed animals on /diagnostics."""
        P = self.P[0]
        centre = P.mean(axis=0)
        d = self.dogs[0]
        alarmed = int((np.sqrt(((P[:, None] - d[None]) ** 2).sum(-1)) < self.sheep.r_s)
                      .any(axis=1).sum()) if len(d) else 0
        self.diag_pub.publish(diagnostic_array(self, [diagnostic_status(
            'herd_sim', OK, f'{len(P)} animals, {len(d)} robots',
            {'steps': self.steps, 'clock_waits': self.waits,
             'centre_x': float(centre[0]), 'centre_y': float(centre[1]),
             'spread_m': float(np.sqrt(((P - centre) ** 2).sum(-1)).mean()),
             'alarmed': alarmed})]))


def main(args=None):
    """Run the node (``ros2 run herd_ros NODE``); exits with its status."""
    exit_process(run_node(HerdSim, args=args))


if __name__ == '__main__':
    main()
