"""Mode ``herd_model`` of the controller: each robot follows its assigned animal's learned
law (:mod:`herd_ros.control.herd_follower`), the model from a model file's ``model.*``
parameters or live from the estimator's ``/herd/model/params`` (with its noise Q_i and,
when fitted, its stop-and-go noise regimes, ``/herd/model/noise_regimes``; with
``match_pace`` each robot's noise scaled to its animal's speed on ``/herd/poses``,
:mod:`herd_ros.control.pace_match`, and with ``match_place`` its place pull to how its
animal keeps its place, :mod:`herd_ros.control.place_match`). The shell of the mode:
parameters, subscriptions and the checks of each model adopted
(:mod:`herd_ros.control.damping`)."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseArray
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, String

from herd_ros.control.animal_steps import AnimalSteps
from herd_ros.control.damping import damping_check
from herd_ros.control.escort import escort_velocity, loop_lag
from herd_ros.control.fleet_observation import FleetObservation
from herd_ros.control.herd_follower import HerdClockHold, HerdFollower, follower_for
from herd_ros.control.pace_match import PaceMatch
from herd_ros.control.place_match import PlaceMatch, stable_shares
from herd_ros.errors import HerdInputError
from herd_ros.estimation.online_regimes import unpack_regimes
from herd_ros.herd_dynamics import HerdDynamics
from herd_ros.model.herd_place import place_offsets
from herd_ros.model.model_structure import ModelStructure
from herd_ros.model.noise_regimes import carry_regime_state
from herd_ros.nodes.ros_common import ParameterError, declare_parameters
from herd_ros.params.controller import HERD_MODEL as HERD_MODEL_DEFAULTS


class HerdModelPolicy:
    """Mode ``herd_model``: each robot follows its assigned animal's learned law.

    Model from the ``model.*`` parameters (``--params-file model.yaml``) or, with
    ``model_source: topic``, live from ``/herd/model/params`` read with the estimator's
    latched ``/herd/model/structure`` (agents, dt, law, field grid, profile: declared once,
    by the estimator; see :func:`~herd_ros.control.herd_follower
    .model_from_parameter_matrix`).
    """

    def __init__(self, node, p: dict):
        self.node = node
        self.robots = node.all_robots
        self.noise = bool(p['noise'])
        self.seed = int(p['seed'])
        self.assignment_given = [str(a) for a in p['assignment']] + \
            [str(a) for a in p['other_assignment']]
        self.follower: HerdFollower | None = None
        self.updates = 0
        self.status = 'waiting for a model'
        self.source = p['model_source']
        self.min_updates = int(p['model_min_updates'])
        self.received = 0
        self.refused_since_adopted = 0
        # each robot's noise matched to its animal's speed on /herd/poses (live models:
        # the estimator's structure says which pose is which animal)
        self.match_pace = bool(p['match_pace']) and self.noise and self.source == 'topic'
        self.pace: PaceMatch | None = None
        # each robot's place pull matched to its animal's place spread (live places)
        self.match_place = bool(p['match_place']) and self.source == 'topic'
        self.place_match: PlaceMatch | None = None
        self._rows_for = self._robot_rows = None   # the structure the robots' rows are for
        # the model steps each animal has been in the herd: a robot follows its animal's
        # live law once it has min_updates of them (animal_steps)
        self.steps: AnimalSteps | None = None
        self.present = None        # (N,) which animals had a pose at the latest herd tick
        self._waiting = ()         # the robots that waited at the last command
        # while it waits a robot escorts its animal (escort) or stands still (hold)
        self.warmup = str(p['wait_mode'])
        self.animal_xy = None      # (R, 2) each robot's animal's latest pose (robot order)
        self.animal_v = None       # (R, 2) ... and its velocity over the last herd tick
        self._last_tick = None     # (t, animals (N, 2)) of the previous herd tick
        self._tick_step = None     # the herd clock's latest step (s)
        self._last_escort = None   # node time (s) of the previous escort command
        # node time at which each robot's law took over (NaN: not yet; a model file: at once)
        self.law_since: np.ndarray | None = None
        if self.source == 'file':
            model = self._model_from_parameters()
            problem, warning = damping_check(model.damping, list(model.agents))
            if problem:
                raise ParameterError(f'model file refused: {problem}')
            if warning:
                node.get_logger().warning(warning)
            self.set_model(model)
        elif self.source == 'topic':
            self.structure, self.noise_cov, self.noise_regimes = None, None, None
            self.home = self.place = None   # /herd/model/home, /place: (μ, K, Σ) or None
            self.regimes_data = None        # the latest /herd/model/noise_regimes, as sent
            self.status = 'waiting for /herd/model/structure (the estimator)'
            latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
            node.create_subscription(String, '/herd/model/structure', self.on_structure,
                                     latched)
            node.create_subscription(Float64MultiArray, '/herd/model/params',
                                     self.on_params, 10)
            node.create_subscription(Float64MultiArray, '/herd/model/noise',
                                     self.on_noise, 10)
            node.create_subscription(Float64MultiArray, '/herd/model/noise_regimes',
                                     self.on_noise_regimes, latched)
            node.create_subscription(Float64MultiArray, '/herd/model/home',
                                     lambda msg: self.on_range(msg, 'home'), 10)
            node.create_subscription(Float64MultiArray, '/herd/model/place',
                                     lambda msg: self.on_range(msg, 'place'), 10)
            node.create_subscription(PoseArray, '/herd/poses', self.on_herd_poses,
                                     QoSProfile(depth=100))
        else:
            raise ParameterError(f'model_source must be file or topic, got {self.source!r}')

    @classmethod
    def from_node(cls, node) :
        """The policy with its parameters declared on ``node``."""
        return cls(node, declare_parameters(node, HERD_MODEL_DEFAULTS))

    # -- model sources ------------------------------------------------------------------
    def _model_from_parameters(self):
        flat = {k: v.value for k, v in self.node.get_parameters_by_prefix('model').items()}
        if 'agents' not in flat:
            raise ParameterError('model_source is file but no model.* parameters were given: '
                                 'pass the model file with --ros-args --params-file model.yaml')
        body: dict = {}
        for key, value in flat.items():
            *path, leaf = key.split('.')
            node = body
            for part in path:
                node = node.setdefault(part, {})
            node[leaf] = value
        try:
            return HerdDynamics.from_dict(body, source='parameters model.*').model
        except HerdInputError as exc:
            raise ParameterError(str(exc)) from None

    def on_structure(self, msg: String):
        """The estimator's model structure: how its parameter rows are read."""
        try:
            structure = ModelStructure.from_json(msg.data)
            self._assignment(list(structure.agents))
        except (HerdInputError, ParameterError) as exc:
            self.status = f'ignored the model structure: {exc}'
            self.node.get_logger().warn(self.status, throttle_duration_sec=10.0)
            return
        if structure != self.structure:
            self.structure = structure
            self._read_regimes()
            self.node.get_logger().info(
                f'model structure: {len(structure.agents)} agents, dt {structure.dt:g} s, '
                f'law {structure.law}, field grid {structure.field_grid[0]} x '
                f'{structure.field_grid[1]}')
            if self.follower is None:
                self.status = 'waiting for a model'

    def _assignment(self, agents: list[str]) -> list[str]:
        n = len(self.robots)
        given = self.assignment_given
        if not given:
            return [agents[k % len(agents)] for k in range(n)]
        if len(given) != n:
            raise ParameterError(f'assignment + other_assignment name {len(given)} animals for '
                                 f'{n} robots (robots + other_robots); give one per robot, '
                                 f'or none to cycle through the model\'s agents')
        unknown = sorted(set(given) - set(agents))
        if unknown:
            raise ParameterError(f'assignment names animal(s) {", ".join(unknown)} not in the '
                                 f'model (agents: {", ".join(agents)})')
        return given

    def set_model(self, model):
        """Drive the robots by ``model`` from now on (one noise generator for the node's life)."""
        # one noise generator for the node's life: a live model is replaced every snapshot,
        # and re-seeding each time would repeat the same draw (a constant push, not noise)
        if not hasattr(self, 'rng'):
            self.rng = np.random.default_rng(self.seed)
        previous = getattr(self.follower, 'noise_source', None)
        self.follower = follower_for(model, self._assignment(list(model.agents)), self.robots,
                                     noise=self.noise, seed=self.rng)
        # ... and the regime chains run on: a rest or a move outlives the model update
        carry_regime_state(previous, self.follower.noise_source)
        self._mark_in_herd()
        if self.pace is not None and len(self.pace.factors) == len(self.follower.robots):
            self.follower.noise_gain = self.pace.factors.copy()
        if self.place_match is not None and \
                len(self.place_match.shares) == len(self.follower.robots):
            self.follower.place_share = self.place_match.shares.copy()
        self.updates += 1
        regimes = (model.meta or {}).get('noise_regimes')
        noise = ('' if not self.noise else
                 f', stop-and-go noise in {np.shape(regimes[0])[1]} regimes' if regimes
                 else ', Gaussian noise')
        self.status = (f'model of {model.n_agents} animals, dt {model.dt:g} s '
                       f'({self.source}){noise}{self._pace_status()}')
        if self.updates == 1 or self.refused_since_adopted:
            a = np.asarray(model.damping, dtype=float)
            self.node.get_logger().info(
                f'adopted {"a" if self.updates == 1 else "again a"} {self.status}: damping '
                f'{a.min():.3f}-{a.max():.3f}'
                + (f' (after {self.refused_since_adopted} refused updates)'
                   if self.refused_since_adopted else ''))
        self.refused_since_adopted = 0

    def on_params(self, msg: Float64MultiArray):
        """Take a model from the estimator's /herd/model/params, read by the latched
        /herd/model/structure."""
        dims = msg.layout.dim
        try:
            if len(dims) != 2:
                raise HerdInputError('/herd/model/params: expected 2 dims (agent x param)')
            rows, cols = dims[0].size, dims[1].size
            data = np.asarray(msg.data, dtype=float)[msg.layout.data_offset:]
            if data.size < rows * cols:
                raise HerdInputError(f'/herd/model/params: {data.size} numbers for '
                                     f'{rows} x {cols}')
            theta = data[:rows * cols].reshape(rows, cols)
            st = self.structure
            if st is None:
                raise HerdInputError('/herd/model/params before /herd/model/structure: '
                                     'ignored until the estimator\'s structure arrives')
            if theta.shape != (len(st.agents), st.n_params):
                raise HerdInputError(f'/herd/model/params is {rows} x {cols}, the structure '
                                     f'says {len(st.agents)} x {st.n_params}')
            self.received += 1
            if self.received <= self.min_updates:
                self.status = (f'warming up: model update {self.received} of '
                               f'{self.min_updates} ignored')
                return
            problem, warning = damping_check(theta[:, 0], list(st.agents))
            if warning:
                self.node.get_logger().warning(warning, throttle_duration_sec=60.0)
            if problem:
                kept = 'keeping the previous model' if self.follower is not None else \
                    'robots hold still until a model is accepted'
                raise HerdInputError(f'/herd/model/params refused: {problem}; {kept}')
            model = HerdDynamics.from_parameters(theta, st, self.noise_cov).model
            # the regimes as the estimator fitted them: the noise of its last window
            # (online_regimes), the herd's present pace; and each animal's home pull
            extra = {'noise_regimes': self.noise_regimes, 'space_use_home': self.home,
                     'herd_place': self.place}
            extra = {k: v for k, v in extra.items() if v is not None}
            if extra:
                import dataclasses
                model = dataclasses.replace(model, meta={**(model.meta or {}), **extra})
            self.set_model(model)
        except (HerdInputError, ParameterError) as exc:
            self.status = f'ignored parameters: {exc}'
            self.refused_since_adopted += 1
            self.node.get_logger().warn(str(exc), throttle_duration_sec=10.0)

    def _agent_rows(self, msg: Float64MultiArray, topic: str, width: int):
        """The (N, width) rows of one of the estimator's per-agent topics, or None (no
        structure yet; a malformed message, logged)."""
        data = np.asarray(msg.data, dtype=float)
        if self.structure is None:
            return None
        n = len(self.structure.agents)
        if data.size != width * n or not np.isfinite(data).all():
            self.node.get_logger().warn(f'{topic}: expected {width * n} finite numbers, '
                                        f'got {data.size}', throttle_duration_sec=10.0)
            return None
        return data.reshape(n, width)

    def on_noise(self, msg: Float64MultiArray):
        """Q_i of every agent from ``/herd/model/noise`` (agent × [qxx, qxy, qyx, qyy])."""
        rows = self._agent_rows(msg, '/herd/model/noise', 4)
        if rows is not None:
            self.noise_cov = rows.reshape(-1, 2, 2)

    def on_range(self, msg: Float64MultiArray, which: str):
        """Each animal's range and the gain of the pull at its edge from
        ``/herd/model/home`` (its positions: ``which`` = 'home') or ``/herd/model/place``
        (its offset from the others' centroid: 'place'), agent × [μx, μy, kxx, kxy, kyx,
        kyy, σxx, σxy, σyx, σyy]; K = 0: none yet
        (:func:`~herd_ros.model.space_use_field.home_drift`,
        :func:`~herd_ros.model.herd_place.place_drift`)."""
        rows = self._agent_rows(msg, f'/herd/model/{which}', 10)
        if rows is not None:
            setattr(self, which, (rows[:, :2], rows[:, 2:6].reshape(-1, 2, 2),
                                  rows[:, 6:].reshape(-1, 2, 2)) if rows[:, 2:6].any()
                    else None)

    def on_noise_regimes(self, msg: Float64MultiArray):
        """The stop-and-go noise of every agent from ``/herd/model/noise_regimes`` (agent ×
        regime × [qxx, qxy, qyx, qyy, transition row]); one regime = Gaussian noise. Latched:
        one that comes before the structure is read when the structure arrives."""
        self.regimes_data = msg.data
        self._read_regimes()

    def _read_regimes(self):
        """Unpack the latest regimes once the structure says how many agents they are for."""
        data = self.regimes_data
        if data is None or self.structure is None:
            return
        try:
            cov, trans = unpack_regimes(data, len(self.structure.agents))
        except HerdInputError as exc:
            self.node.get_logger().warn(str(exc), throttle_duration_sec=10.0)
            return
        self.noise_regimes = (cov, trans) if cov.shape[1] > 1 else None

    def _pace_status(self) -> str:
        """The pace match's factors for the status line (empty before its first change)."""
        if self.pace is None or not self.pace.updates:
            return ''
        f = self.pace.factors[self.node.owned]
        return f', pace-matched noise x{f.min():.2f}-{f.max():.2f}'

    def robot_rows(self) -> list[int] | None:
        """Each robot's animal's row of the estimator's agents (None before the structure,
        or when the assignment does not fit it; a model file has none)."""
        st = getattr(self, 'structure', None)
        if st is None:
            return None
        if self._rows_for is not st:
            try:
                where = {a: i for i, a in enumerate(st.agents)}
                self._robot_rows = [where[a] for a in self._assignment(list(st.agents))]
            except ParameterError:
                self._robot_rows = None
            self._rows_for = st
        return self._robot_rows

    def on_herd_poses(self, msg: PoseArray):
        """A herd tick: the model steps each animal has been in the herd
        (:class:`~herd_ros.control.animal_steps.AnimalSteps`), and each robot against its
        animal for the pace match (:class:`~herd_ros.control.pace_match.PaceMatch`; the
        robots' positions are their latest odometry, timed by its own stamps: at a fast
        replay it arrives in bursts); each robot's animal's pose and velocity for the
        escort of a robot that waits (:mod:`herd_ros.control.escort`)."""
        st = self.structure
        if st is None or len(msg.poses) != len(st.agents):
            return
        animals = np.array([(q.position.x, q.position.y) for q in msg.poses], dtype=float)
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if self.steps is None or self.steps.dt != st.dt or len(self.steps.count) != len(
                st.agents):
            self.steps = AnimalSteps(len(st.agents), st.dt)
        self.steps.observe(t, animals)
        self.present = np.isfinite(animals).all(axis=-1)
        self._mark_in_herd()
        follower, index = self.follower, self.robot_rows()
        if index is not None:
            self.animal_xy = animals[index]
            v = np.full(animals.shape, np.nan)
            last = self._last_tick
            if last is not None and t > last[0] and last[1].shape == animals.shape:
                v = (animals - last[1]) / (t - last[0])
                self._tick_step = t - last[0]
            self.animal_v = v[index]
        self._last_tick = (t, animals)
        if index is None:
            return
        if follower is not None:
            self._match_place(t, animals, follower, index)
        if not self.match_pace:
            return
        # a robot and its animal count from the tick its law took over (_under_law)
        if self.pace is None or self.pace.lag != st.dt or self.pace.n != len(index):
            self.pace = PaceMatch(len(index), st.dt)
        node = self.node
        if self.pace.observe(t, animals[index], node.odom_stamp,
                             self._under_law(node.positions)) and follower is not None:
            follower.noise_gain = self.pace.factors.copy()
            self.status = self.status.split(', pace-matched')[0] + self._pace_status()
            f = self.pace.factors[node.owned]
            node.get_logger().info(f'pace match: noise factors {f.min():.2f}-{f.max():.2f} '
                                   f'(each robot\'s speed against its animal\'s)',
                                   throttle_duration_sec=30.0)

    def _match_place(self, t: float, animals: np.ndarray, follower, index):
        """Each robot's offset from the other robots' centroid against its animal's from
        the other animals' on this herd tick, for the place match
        (:class:`~herd_ros.control.place_match.PlaceMatch`)."""
        place = (follower.model.meta or {}).get('herd_place')
        if not self.match_place or place is None or len(index) != len(follower.robots):
            return
        if self.place_match is None or self.place_match.n != len(index):
            self.place_match = PlaceMatch(len(index))
        robots = np.asarray(self.node.positions, dtype=float).reshape(-1, 2)
        counted = np.isfinite(robots).all(axis=-1) & follower.in_herd
        robot_d = np.where(counted[:, None], place_offsets(robots, counted), np.nan)
        robot_d = self._under_law(robot_d)       # an escorting robot's place is not the law's
        animal_d = place_offsets(animals)[index]
        limit = stable_shares(follower.damping, place[1], follower.dt, len(index))
        if self.place_match.observe(t, animal_d, robot_d, place[0], place[2], limit):
            follower.place_share = self.place_match.shares.copy()
            owned = np.asarray(self.node.owned, dtype=bool)
            s = self.place_match.shares[owned] if owned.any() else self.place_match.shares
            self.node.get_logger().info(
                f'place match: shares {s.min():.2f}-{s.max():.2f} of the place pull inside '
                f'the range (each robot\'s place spread against its animal\'s)',
                throttle_duration_sec=30.0)

    def _mark_in_herd(self):
        """Tell the follower which robots' animals have a pose at the latest herd tick (the
        others do not count in the robots' centroid for the place pulls)."""
        present, index = self.present, self.robot_rows()
        if self.follower is None or present is None or index is None or \
                len(index) != len(self.follower.robots):
            return
        self.follower.in_herd = present[index]

    def _under_law(self, rows) -> np.ndarray:
        """``rows`` (R, 2), NaN for the robots whose law has not taken over yet."""
        rows = np.array(rows, dtype=float).reshape(-1, 2)
        since = self.law_since
        if since is None or len(since) != len(rows):
            return np.full_like(rows, np.nan)        # no command yet: none under a law
        return np.where(np.isnan(since)[:, None], np.nan, rows)

    def waiting(self) -> np.ndarray | None:
        """(R,) the robots whose animal has been in the herd for fewer than
        ``model_min_updates`` model steps (they escort their animal or hold still,
        ``wait_mode``), or None when none waits."""
        if self.source != 'topic' or self.min_updates <= 0:
            return None
        index = self.robot_rows()
        if index is None:
            return None
        if self.steps is None:
            return np.ones(len(index), dtype=bool)
        wait = ~self.steps.ready(self.min_updates)[index]
        return wait if wait.any() else None

    # -- the policy -----------------------------------------------------------------------
    def command(self, state: FleetObservation) -> np.ndarray:
        """The law's command: held on the herd clock and stepped at its ticks when the
        controller ticks faster than the model (:class:`HerdClockHold`), else advanced by
        the elapsed fraction of model steps (:meth:`HerdFollower.advance`)."""
        if self.follower is None:
            return self._warmup(state, np.zeros_like(state.positions),
                                np.ones(len(state.positions), dtype=bool))
        dt = self.follower.dt
        if state.period < dt:
            if getattr(self, 'hold', None) is None or self.hold.dt != dt:
                self.hold = HerdClockHold(dt)
            command = self.hold.command(self.follower, state.last_command, state.positions,
                                        state.time, state.active)
        else:
            self.hold = None
            command = self.follower.advance(state.last_command, state.positions,
                                            state.period, state.active)
        wait = self.waiting()
        waiting = () if wait is None else tuple(np.flatnonzero(wait))
        if waiting != self._waiting:
            self._waiting = waiting
            names = [self.robots[k] for k in waiting if k < len(self.robots)]
            doing = 'escort their animal' if self.warmup == 'escort' else 'hold still'
            self.node.get_logger().info(
                f'{", ".join(names)} {doing} until their animal has been in the herd '
                f'for {self.min_updates} model steps' if names else
                'every robot follows its animal\'s law')
        if wait is None or len(wait) != len(command):
            wait = np.zeros(len(command), dtype=bool)
        return self._warmup(state, command, wait)

    def _warmup(self, state: FleetObservation, command: np.ndarray,
                wait: np.ndarray) -> np.ndarray:
        """``command`` with each waiting robot's replaced: towards its animal's latest pose
        (``escort``, :func:`~herd_ros.control.escort.escort_velocity` at τ the herd clock's
        step) or 0 (``hold``); records when each robot's law took over
        (:attr:`law_since`)."""
        n = len(command)
        if self.law_since is None or len(self.law_since) != n:
            self.law_since = np.full(n, np.nan)
        if self.follower is not None:
            start = ~wait & np.isnan(self.law_since)
            self.law_since[start] = state.time
        if not wait.any():
            return command
        hold = np.zeros_like(command)
        st = getattr(self, 'structure', None) or self.follower
        animals = self.animal_xy
        if self.warmup == 'escort' and st is not None and animals is not None and \
                len(animals) == n:
            u = self.animal_v if self.animal_v is not None and len(self.animal_v) == n \
                else None
            lag = loop_lag(state.pose_age, state.time - self._last_escort
                           if self._last_escort is not None else None)
            hold = escort_velocity(state.positions, animals, self._tick_step or st.dt, u,
                                   ahead=state.time - self._last_tick[0], lag=lag)
            self._last_escort = state.time
        return np.where(wait[:, None], hold, command)
