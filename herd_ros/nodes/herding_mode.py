"""Controller mode ``herding``: the robots drive the animals of ``/herd/poses`` into a goal
circle (issue 27).

Each tick the policy takes the latest animal positions (NaN ones ignored) and the robots'
odometry, and the ``herder`` gives each robot a target:

* ``strombom``: Strömbom's shepherd (:func:`herd_ros.herding.strombom.strombom_targets`:
  collect the furthest animal while the herd is not gathered, drive from behind its centre
  otherwise; several robots collect the furthest few and drive from an arc);
* ``model``: the model herder (:class:`herd_ros.herding.model_herder.ModelHerder`,
  receding-horizon control over the animals' learned response to the robots). At the first
  herd it learns that response, in a spawned worker process (the fit is Python-heavy: in a
  thread it held the node's GIL, and on a slow machine the herd was home before it was
  done), from simulated recordings of as many animals and robots
  (:func:`~herd_ros.herding.model_herder.learn_model_herder`; 10-30 s for 14 animals;
  Strömbom's shepherd herds meanwhile, or with ``model_warmup: hold`` the robots hold
  still), then it is called once per new herd
  snapshot (the law's 1 s step) and refits the response online from what it sees.

:func:`~herd_ros.herding.strombom.herder_velocities` turns a target into a velocity of
``herder_speed`` (with Strömbom's heading noise), zero within ``stop_factor`` r_a of an
animal. Once every animal is inside the goal the robots hold still. RViz markers on
``/herding/markers`` (visualization_msgs/MarkerArray, map frame): the goal circle, the
herd's centre and each robot's target.
"""
from __future__ import annotations

import threading

import numpy as np
from geometry_msgs.msg import PoseArray
from visualization_msgs.msg import Marker, MarkerArray

from herd_ros.herding.strombom import (SheepParams, ShepherdParams, herd_in_goal,
                                       herder_velocities, strombom_targets)
from herd_ros.nodes.ros_common import (ParameterError, declare_parameters, pose_array_xy,
                                       stamp_to_seconds)
from herd_ros.params.controller import HERDING as HERDING_DEFAULTS


class HerdingPolicy:
    """Mode ``herding`` (see the module docstring); ``command(state)`` -> (R, 2) m/s."""

    def __init__(self, node, p: dict):
        self.node = node
        goal = np.asarray(list(p['goal']), dtype=float)
        if goal.shape != (2,) or not np.isfinite(goal).all():
            raise ParameterError(f'goal must be [x, y] (m), got {list(p["goal"])}')
        self.goal, self.radius = goal, float(p['goal_radius'])
        self.sheep = SheepParams(n_neighbours=1, r_a=float(p['animal_spacing']))
        self.shepherd = ShepherdParams(speed=float(p['herder_speed']),
                                       e=float(p['herder_noise']),
                                       stop_factor=float(p['stop_factor']),
                                       arc_deg=float(p['drive_arc_deg']))
        self.rng = np.random.default_rng([int(p['herding_seed']), 27])
        self.topic = str(p['herd_topic'])
        self.animals = None
        self.animals_time = np.nan
        self.updates = 0
        self.phase = 'waiting'
        self.targets = np.zeros((0, 2))
        self.markers_period = float(p['markers_period_s'])
        self._last_markers = -np.inf
        node.create_subscription(PoseArray, self.topic, self.on_poses, 10)
        self.markers_pub = node.create_publisher(MarkerArray, '/herding/markers', 10)
        self.status = f'waiting for the animals on {self.topic}'
        self.herder = str(p['herder'])
        self.warmup = str(p['model_warmup'])
        self.model = None                 # the ModelHerder, once learned
        self._learning = None             # {'thread' (waits for the process), 'herder' | 'error'}
        self._model_state: dict = {}
        self._planned_update = -1
        self._model_targets = None

    @classmethod
    def from_node(cls, node) -> 'HerdingPolicy':
        """The policy with its parameters declared on ``node``."""
        return cls(node, declare_parameters(node, HERDING_DEFAULTS))

    def on_poses(self, msg: PoseArray):
        """Take the animals' positions (finite ones) from the herd topic."""
        self.animals = pose_array_xy(msg, finite=True)
        self.animals_time = stamp_to_seconds(msg.header.stamp)
        self.updates += 1

    def command(self, state) -> np.ndarray:
        """World velocities (R, 2) of the herder; zero once the herd is home."""
        out = np.full_like(state.positions, np.nan)
        present = state.active & np.isfinite(state.positions).all(axis=1)
        P = self.animals
        if P is None or not len(P) or not present.any():
            out[present] = 0.0
            return out
        dogs = state.positions[present]
        if herd_in_goal(P[None], self.goal, self.radius)[0]:
            self.phase = 'home'
            out[present] = 0.0
            self.targets = dogs.copy()
        else:
            targets, driving = strombom_targets(P[None], dogs[None], self.goal, self.sheep,
                                                self.shepherd)
            self.phase = 'driving' if driving[0] else 'collecting'
            planned = self._planned(P, dogs) if self.herder == 'model' else None
            if planned is not None:
                targets, self.phase = planned, 'planning'
            if self._warming_up() and self.warmup == 'hold':
                self.phase = 'holding'
                out[present] = 0.0
                self.targets = dogs.copy()
            else:
                self.targets = targets[0]
                out[present] = herder_velocities(dogs[None], targets, P[None], self.sheep,
                                                 self.shepherd, self.rng, state.period)[0]
        learning = (' (Strömbom\'s shepherd while the model herder learns the response)'
                    if self._warming_up() and self.warmup == 'strombom' else '')
        self.status = {'home': 'the herd is inside the goal: holding still',
                       'holding': 'holding still while the model herder learns the response',
                       'driving': 'driving the herd to the goal',
                       'collecting': 'collecting a straggler',
                       'planning': 'the model herder drives the herd to the goal'}[self.phase] + \
            learning + f' ({len(P)} animals, goal {self.goal.tolist()} r {self.radius:g} m)'
        if state.time - self._last_markers >= self.markers_period - 1e-9:
            self._last_markers = state.time
            self.publish_markers(P)
        return out

    def _warming_up(self) -> bool:
        """The model herder is asked for and still learning (not failed)."""
        return (self.herder == 'model' and self.model is None and self._learning is not None
                and not self._learning.get('failed'))

    def _learn(self, n_animals: int, n_robots: int):
        """Learn the model herder in a worker process (module docstring): a spawned
        interpreter, so the fit (a minute of Python on a slow machine) does not hold the
        node's GIL; a thread waits for it."""
        box = {}

        def work():
            import multiprocessing

            from herd_ros.herding.model_herder import learn_model_herder_into
            ctx = multiprocessing.get_context('spawn')
            recv, send = ctx.Pipe(duplex=False)
            # a daemon: it ends with the node, whatever it was doing
            proc = ctx.Process(target=learn_model_herder_into, name='herding-learn',
                               args=(send, n_animals, n_robots), daemon=True)
            try:
                proc.start()
                send.close()
                kind, value = recv.recv()
                box['herder' if kind == 'herder' else 'error'] = value
            except Exception as exc:        # noqa: BLE001 (reported once; Strömbom herds on)
                box['error'] = (f'{type(exc).__name__}: {exc}' if not isinstance(exc, EOFError)
                                else 'the learning process ended without a result')
            finally:
                recv.close()
                proc.join(timeout=5.0)
        self.node.get_logger().info(
            f'herding: learning the response of {n_animals} animals to {n_robots} '
            f'robot{"s" * (n_robots > 1)} from simulated recordings; '
            + ("Strömbom's shepherd herds meanwhile" if self.warmup == 'strombom'
               else 'the robots hold still meanwhile'))
        box['thread'] = threading.Thread(target=work, name='herding-learn', daemon=True)
        box['thread'].start()
        return box

    def _planned(self, P: np.ndarray, dogs: np.ndarray):
        """The model herder's targets (1, R, 2), or None while it learns (or if it could
        not): replanned once per new herd snapshot."""
        if self.model is None:
            if self._learning is None:
                self._learning = self._learn(len(P), len(dogs))
            box = self._learning
            if box['thread'].is_alive() or box.get('failed'):
                return None
            if 'error' in box:
                box['failed'] = True
                self.node.get_logger().error(
                    f'herding: the model herder could not learn ({box["error"]}); '
                    'Strömbom\'s shepherd herds on')
                return None
            self.model = box['herder']
            self.node.get_logger().info('herding: the model herder drives from now on')
        if self.updates != self._planned_update or self._model_targets is None:
            self._planned_update = self.updates
            st = self._model_state
            if st.get('shape') != (len(P), len(dogs)):      # an animal or robot came or went
                st.clear()
                st['shape'] = (len(P), len(dogs))
            st['live'] = np.zeros(1, np.int64)
            try:
                self._model_targets = self.model(P[None], dogs[None], self.goal, self.sheep,
                                                 self.shepherd, st)
            except Exception as exc:        # noqa: BLE001 (reported once; Strömbom herds on)
                self._learning['failed'], self.model = True, None
                self.node.get_logger().error(
                    f'herding: the model herder failed ({type(exc).__name__}: {exc}); '
                    'Strömbom\'s shepherd herds on')
                return None
        return self._model_targets

    def publish_markers(self, P: np.ndarray):
        """Publish the goal, the herd's centre and each robot's target on /herding/markers."""
        stamp = self.node.get_clock().now().to_msg()

        def marker(mid, kind, xy, scale, rgba, z=0.0):
            m = Marker()
            m.header.frame_id = 'map'
            m.header.stamp = stamp
            m.ns, m.id, m.type, m.action = 'herding', mid, kind, Marker.ADD
            m.pose.position.x, m.pose.position.y, m.pose.position.z = (
                float(xy[0]), float(xy[1]), z)
            m.pose.orientation.w = 1.0
            m.scale.x, m.scale.y, m.scale.z = scale
            m.color.r, m.color.g, m.color.b, m.color.a = rgba
            return m
        d = 2 * self.radius
        ms = [marker(0, Marker.CYLINDER, self.goal, (d, d, 0.1), (0.2, 0.8, 0.2, 0.3)),
              marker(1, Marker.SPHERE, P.mean(axis=0), (2.0, 2.0, 2.0), (0.9, 0.6, 0.1, 0.9))]
        for k, t in enumerate(self.targets):
            ms.append(marker(2 + k, Marker.SPHERE, t, (1.5, 1.5, 1.5), (0.2, 0.4, 1.0, 0.9)))
        self.markers_pub.publish(MarkerArray(markers=ms))
