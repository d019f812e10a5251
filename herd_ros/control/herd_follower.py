"""Robots that move like the herd: robot k follows the learned law of its assigned animal.

The herd model (Schwager, Anderson & Rus, FSR 2007, eq. 2) per animal i is

    u_i^{τ+1} = a_i u_i^τ + Σ_{j≠i} f_ij(p_i^τ, p_j^τ) + g_i(p_i^τ) + w_i^τ,   w_i ~ N(0, Q_i)

Robot k is assigned animal A(k) and uses that animal's damping a_A(k), field g_A(k) and noise
Q_A(k); its neighbours are the **other robots**, robot j standing in for animal A(j), so

    u_k^{τ+1} = a_A(k) u_k^τ + Σ_{j≠k} f_{A(k)A(j)}(p_k, p_j) + g_A(k)(p_k) + w_k^τ.

Two robots assigned the same animal have no learned pair law (an animal has no θ with
itself); they use that animal's mean θ1, θ2 over its neighbours, so they still keep the
herd's typical spacing instead of ignoring each other.

**Rate vs model step.** The law is a discrete map with step Δt (``model.dt``); the
controller runs at a period h = 1/rate_hz that need not equal Δt. The controller node holds
the law on the herd clock when h < Δt (:class:`HerdClockHold`: stepped at the ticks k·Δt,
which is how the animals' velocities were measured). :meth:`HerdFollower.advance` itself
advances the law by the fraction α = h/Δt of a model step (explicit Euler of the same map
in model time, which is the law itself at α = 1; the node uses it for α ≥ 1)::

    u ← u + α [(a − 1) u + Σ_j f(p) + g(p)] + √α L ξ,   L Lᵀ = Q,  ξ ~ N(0, I)

This keeps the fixed points (u* = (Σf + g)/(1 − a)), the relaxation time Δt/(1 − a) in
seconds and, to first order, the noise variance accumulated per model step (α steps of
variance αQ add to Q). For α > 1 (a controller slower than the model) the advance is split
into ⌈α⌉ equal sub-steps, propagating the positions internally by p ← p + (α/n) Δt u, so
the map stays stable. The velocity state u is the command the controller actually issued
last tick (after the safety layer), which is the anti-windup: a robot held by the fence
does not accumulate velocity against it. Positions p are those measured at the tick, so
the feedback uses the freshest positions (one period fresher than the paper's p^τ; the two
coincide as α → 0).
"""
from __future__ import annotations

import numpy as np

from herd_ros.errors import HerdInputError
from herd_ros.model.herd_model import AgentLaw, HerdModel, pairwise_geometry
from herd_ros.model.noise_regimes import noise_for, subset_regimes
from herd_ros.model.herd_place import subset_place
from herd_ros.model.space_use_field import subset_home

#: Herd-clock steps the hold steps the law through at once; a longer jump of the clock (sim
#: time starting, a replay resumed) restarts the law from what the robots do.
MAX_HELD_STEPS = 50

#: Distances below this (m) are treated as this in the repulsion θ2/d (co-located robots).
MIN_DISTANCE = 1e-3


def _robot_assignment(model, assignment, robots=None) -> tuple[list[str], list[int]]:
    """The robot names (default robot_1 …) and, per robot, the index of its animal in the
    model; one clear error for a count mismatch or an animal the model does not have."""
    assignment = [str(a) for a in assignment]
    robots = list(robots) if robots is not None else [f'robot_{k + 1}'
                                                      for k in range(len(assignment))]
    if len(robots) != len(assignment):
        raise HerdInputError(f'assignment has {len(assignment)} animals for {len(robots)} robots')
    unknown = sorted(set(assignment) - set(model.agents))
    if unknown:
        raise HerdInputError(f'assignment names animal(s) {", ".join(unknown)} that the model '
                             f'does not have (model agents: {", ".join(model.agents)})')
    return robots, [model.agents.index(a) for a in assignment]


def _robot_meta(model, index) -> dict:
    """The robots' model meta: each robot its animal's velocity memory, noise regimes,
    space-use home pull and place in the herd."""
    return {'velocity_memory': model.velocity_memory[np.asarray(index)],
            **subset_regimes(model.meta, index), **subset_home(model.meta, index),
            **subset_place(model.meta, index)}


def _robot_alignment(model, index):
    """The robots' alignment: each robot its animal's kernel weights (none without)."""
    al = getattr(model, 'alignment', None)
    if al is None:
        return None
    from herd_ros.model.alignment import VelocityAlignment
    return VelocityAlignment(al.kernel, al.coef[np.asarray(index)])


def robot_herd_model(model: HerdModel, assignment: list[str],
                     robots: list[str] | None = None) -> HerdModel:
    """A :class:`HerdModel` over robots: robot k carries the law of animal ``assignment[k]``.

    Pair terms come from the animals' pair parameters (θ1, θ2 of A(k) toward A(j)); for two
    robots on the same animal the mean of A(k)'s θ1, θ2 over its neighbours is used.
    """
    robots, index = _robot_assignment(model, assignment, robots)
    n = model.n_agents
    off = ~np.eye(n, dtype=bool)
    count = np.maximum(off.sum(1), 1)
    mean1 = (model.theta1 * off).sum(1) / count
    mean2 = (model.theta2 * off).sum(1) / count
    t1 = model.theta1[np.ix_(index, index)]
    t2 = model.theta2[np.ix_(index, index)]
    same = np.equal.outer(index, index)
    t1 = np.where(same, mean1[index][:, None], t1)
    t2 = np.where(same, mean2[index][:, None], t2)
    laws = {}
    for k, robot in enumerate(robots):
        law = model.laws[model.agents[index[k]]]
        others = [j for j in range(len(robots)) if j != k]
        laws[robot] = AgentLaw(damping=law.damping, neighbors=[robots[j] for j in others],
                               theta1=t1[k, others], theta2=t2[k, others], basis=law.basis,
                               field_u=law.field_u, field_v=law.field_v,
                               noise_cov=law.noise_cov)
    return HerdModel(agents=robots, dt=model.dt, laws=laws, frame_id=model.frame_id,
                     datum=model.datum, meta=_robot_meta(model, index),
                     alignment=_robot_alignment(model, index))


class HerdFollower:
    """Evaluate the assigned laws for a fleet of R robots, vectorised.

    Attributes:
        model: the robot :class:`HerdModel` (robots as agents), see :func:`robot_herd_model`.
        damping (R,), theta1 (R, R), theta2 (R, R): the packed law parameters.
        noise_source: draws w, N(0, Q_A(k)) or A(k)'s noise regimes
            (:func:`~herd_ros.model.noise_regimes.noise_for`).
        noise: whether w is drawn.
        noise_gain (R,): a factor on each robot's noise std on top of the model's (the
            live pace match, :mod:`herd_ros.control.pace_match`); 1 by default.
        place_share (R,): each robot's share of its place pull's linear part inside its
            range (the live place match, :mod:`herd_ros.control.place_match`); 0 by
            default (the pull at the range's edge only).
    """

    def __init__(self, model: HerdModel, assignment: list[str], robots: list[str] | None = None,
                 noise: bool = False, seed=None):
        self.model = robot_herd_model(model, assignment, robots)
        self.robots = list(self.model.agents)
        self.dt = float(model.dt)
        self.damping = self.model.damping
        self.theta1 = self.model.theta1
        self.theta2 = self.model.theta2
        self.noise = bool(noise)
        self.noise_source = noise_for(self.model, seed)
        self.noise_gain = np.ones(len(self.robots))
        self.place_share = np.zeros(len(self.robots))
        self.in_herd = np.ones(len(self.robots), dtype=bool)

    def environment(self, positions: np.ndarray, active: np.ndarray) -> np.ndarray:
        """g_k of every active robot (0 for the others): its field and home pull at its own
        position, and the pull to its place among the other robots that are active and
        whose animal is in the herd (:attr:`in_herd`: the offsets its animal's place was
        learned from leave absent animals out, so a robot whose animal's collar is silent
        or has not started must not move the others' centroid), at its
        :attr:`place_share` inside its range."""
        p = np.where(active[:, None], positions, np.nan)
        counted = active & (self.in_herd if len(self.in_herd) == len(p) else True)
        share = self.place_share if np.shape(self.place_share) == (len(p),) and \
            self.place_share.any() else None
        return np.nan_to_num(self.model.environment(p, counted=counted, share=share))

    def drift(self, positions: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """Σ_{j active, j≠k} f_kj(p_k, p_j) + g_k(p_k) for every robot: (R, 2) -> (R, 2).

        Inactive robots (stale odometry, NaN positions) exert nothing on the others.
        """
        p = np.asarray(positions, dtype=float).reshape(-1, 2)
        r = len(p)
        active = np.ones(r, bool) if active is None else np.asarray(active, bool)
        active = active & np.isfinite(p).all(-1)
        p_safe = np.where(active[:, None], p, 0.0)
        _, dist, unit = pairwise_geometry(p_safe)
        magnitude = self.theta1 - self.theta2 / np.maximum(dist, MIN_DISTANCE)
        magnitude = np.where(active[None, :] & ~np.eye(r, dtype=bool), magnitude, 0.0)
        interaction = (magnitude[..., None] * np.nan_to_num(unit)).sum(-2)
        return interaction + self.environment(p, active)

    def alignment(self, positions: np.ndarray, velocity: np.ndarray,
                  active: np.ndarray | None = None):
        """A_k of every robot (the velocity alignment its animal learned,
        :mod:`herd_ros.model.alignment`) toward the other active robots; 0 without one."""
        al = self.model.alignment
        if al is None:
            return 0.0
        p = np.asarray(positions, dtype=float).reshape(-1, 2)
        active = np.ones(len(p), bool) if active is None else np.asarray(active, bool)
        p = np.where((active & np.isfinite(p).all(-1))[:, None], p, np.nan)
        return np.nan_to_num(al.acceleration(p, velocity))

    def advance(self, velocity: np.ndarray, positions: np.ndarray, elapsed: float,
                active: np.ndarray | None = None) -> np.ndarray:
        """New velocities (R, 2) after ``elapsed`` seconds of the law from u (R, 2) at p (R, 2).

        u ← u + α[(a − 1)u + Σf + g + A] + √α L ξ in ⌈α⌉ sub-steps, α = elapsed/Δt (module
        doc; A the velocity alignment toward the other robots when the law has one);
        with a velocity memory κ < 1, u ← u + α[a ū − u + Σf + g] and ū ← ū + α κ (u − ū),
        ū carried from tick to tick.
        """
        u = np.asarray(velocity, dtype=float).reshape(-1, 2).copy()
        p = np.asarray(positions, dtype=float).reshape(-1, 2).copy()
        alpha = float(elapsed) / self.dt
        if alpha <= 0:
            return u
        steps = int(np.ceil(alpha - 1e-12))
        beta = alpha / steps
        kappa = self.model.velocity_memory                            # (R,)
        plain = bool((kappa == 1.0).all())
        mean = self._mean_velocity(u, kappa)
        for _ in range(steps):
            damped = ((self.damping[:, None] - 1.0) * u if plain
                      else self.damping[:, None] * mean - u)         # a ū − u
            change = beta * (damped + self.drift(p, active)
                             + self.alignment(p, u if plain else mean, active))
            if self.noise:
                change += self.noise_gain[:, None] * self.noise_source.draw(beta)
            p = p + beta * self.dt * u
            u = u + change
            mean = u if plain else np.where((kappa == 1.0)[:, None], u,
                                            mean + beta * kappa[:, None] * (u - mean))
        self._mean = mean
        return u

    def _mean_velocity(self, u: np.ndarray, kappa: float) -> np.ndarray:
        """ū of every robot (velocity memory, :mod:`herd_ros.model.velocity_memory`): the
        one carried from the last tick, restarted at u where there is none (first tick, a
        robot that was inactive); u itself at κ = 1."""
        mean = getattr(self, '_mean', None)
        if (kappa == 1.0).all() or mean is None or mean.shape != u.shape:
            return u.copy()
        return np.where(np.isfinite(mean) & (kappa != 1.0)[:, None], mean, u)


class HerdClockHold:
    """The discrete law on the herd clock, for a controller that ticks faster than the model.

    The model is a map from one herd-clock tick k·Δt to the next, and its velocity u^k is the
    displacement over [kΔt, (k+1)Δt] divided by Δt (eq. 2: p^{k+1} = p^k + Δt u^k). Robots
    that should *measure* like the animals on that clock must therefore move at u^k over that
    interval: a zero-order hold of the law, stepped when the node clock crosses a tick.
    Splitting the map into fractions of a step per controller tick (:meth:`HerdFollower.advance`
    with α < 1) does not do this: with a damping a its stationary velocity variance is
    (1 + a)/2 of the law's, and a hold whose phase is off the ticks averages two
    velocities, (f² + (1 − f)² + 2f(1 − f)a) of the variance for a phase f — both make the
    robots slower than the animals (measured: 29–33 % in mean and std of speed with the
    cows' a ≈ 0 at a 20 s clock).

    A controller notices a tick δ late (its period, the /clock granularity). Over the rest of
    the interval it commands v = (Δt u^k − δ v_prev)/(Δt − δ), v_prev being what the robot
    did since the tick, so the displacement over [kΔt, (k+1)Δt] is exactly Δt u^k (a
    deadbeat correction; for δ ≥ Δt/2 it commands u^k). The law's velocity state is u^{k−1}
    where the safety layer issued what was asked, and what was issued where it changed the
    command (the anti-windup of :class:`HerdFollower`).
    """

    def __init__(self, dt: float):
        self.dt = float(dt)
        self.index = None          # the last tick the law was stepped at
        self.law = None            # u^k (R, 2)
        self.asked = None          # the command asked for last (R, 2)

    def command(self, follower, issued: np.ndarray, positions: np.ndarray, now: float,
                active: np.ndarray | None = None) -> np.ndarray:
        """The command (R, 2) at node time ``now``; ``issued`` (R, 2) is what the safety
        layer let through last tick."""
        issued = np.asarray(issued, dtype=float).reshape(-1, 2)
        k = int(np.floor(now / self.dt + 1e-9))
        fresh = (self.law is None or self.law.shape != issued.shape or self.index is None
                 or k < self.index or k - self.index > MAX_HELD_STEPS)
        if not fresh and k == self.index:
            return self.asked.copy()
        if fresh:
            state, steps = issued, 1
        else:
            clipped = ~np.isclose(issued, self.asked, rtol=1e-9, atol=1e-12).all(-1)
            state = np.where(clipped[:, None], issued, self.law)
            steps = k - self.index
        self.law = follower.advance(state, positions, steps * self.dt, active)
        self.index = k
        late = now - k * self.dt
        if not fresh and 0.0 < late < 0.5 * self.dt:
            asked = (self.dt * self.law - late * issued) / (self.dt - late)
        else:
            asked = self.law.copy()
        self.asked = np.where(np.isfinite(asked), asked, self.law)
        return self.asked.copy()


def model_from_parameter_matrix(theta: np.ndarray, agents: list[str], dt: float,
                                grid, noise_cov: np.ndarray | None = None) -> HerdModel:
    """A pairwise :class:`HerdModel` from the estimator's parameter matrix (N, P).

    Row i is θ_i in the order of doc/formats.md, [a_i, θ1_i·, θ2_i·, θu_i·, θv_i·], the
    neighbours being the other agents in ``agents`` order, and the field on **every** centre
    of ``grid`` (a :class:`~herd_ros.model.rbf_field.FieldGrid`, σ = 2/3 spacing, no pruning),
    so P = 1 + 2(N − 1) + 2K with K = nx·ny. ``noise_cov`` (N, 2, 2) is Q_i from the
    estimator's ``/herd/model/noise`` (zero until it has arrived).
    """
    from herd_ros.model.rbf_field import RbfBasis

    theta = np.asarray(theta, dtype=float)
    n = len(agents)
    basis = RbfBasis.from_grid(grid)
    k = basis.size
    width = 1 + 2 * (n - 1) + 2 * k
    if theta.shape != (n, width):
        got = ' x '.join(str(d) for d in theta.shape)
        raise HerdInputError(f'/herd/model/params: expected {n} agents x {width} parameters '
                             f'(1 + 2·{n - 1} pair + 2·{k} field for a {grid.nx}x{grid.ny} '
                             f'grid), got {got}')
    if not np.isfinite(theta).all():
        raise HerdInputError('/herd/model/params: parameters contain NaN or inf')
    laws = {}
    m = n - 1
    for i, agent in enumerate(agents):
        row = theta[i]
        laws[agent] = AgentLaw(damping=float(row[0]),
                               neighbors=[a for a in agents if a != agent],
                               theta1=row[1:1 + m], theta2=row[1 + m:1 + 2 * m], basis=basis,
                               field_u=row[1 + 2 * m:1 + 2 * m + k],
                               field_v=row[1 + 2 * m + k:1 + 2 * m + 2 * k],
                               noise_cov=(np.zeros((2, 2)) if noise_cov is None
                                          else noise_cov[i]))
    return HerdModel(agents=list(agents), dt=float(dt), laws=laws)


def robot_shared_model(model, assignment: list[str], robots: list[str] | None = None):
    """A :class:`~herd_ros.model.shared_law.SharedLawModel` over robots: robot k carries the
    damping, distance profile F_A(k), field and noise of animal ``assignment[k]``; its
    neighbours are the other robots within the interaction radius (the shared law needs no
    pair parameters, so any assignment works, two robots on one animal included)."""
    from herd_ros.model.shared_law import SharedLawModel
    robots, idx = _robot_assignment(model, assignment, robots)
    # a robot on a distinguished animal (a dog) is distinguished among the robots: every
    # robot sees it through its own animal's profile of that animal
    own_robots = [r for r, i in zip(robots, idx) if model.agents[i] in model.own_agents]
    own_coef = None
    if own_robots:
        slot = [model.own_agents.index(model.agents[idx[robots.index(r)]]) for r in own_robots]
        own_coef = model.own_coef[np.ix_(idx, slot)]
    return SharedLawModel(agents=robots, dt=model.dt, profile=model.profile,
                          own_agents=own_robots,
                          own_profile=model.own_profile if own_robots else None,
                          own_coef=own_coef,
                          damping=model.damping[idx], profile_coef=model.profile_coef[idx],
                          bases=[model.bases[i] for i in idx],
                          field_u=[model.field_u[i] for i in idx],
                          field_v=[model.field_v[i] for i in idx],
                          noise_cov=model.noise_cov[idx], frame_id=model.frame_id,
                          datum=model.datum, meta=_robot_meta(model, idx),
                          alignment=_robot_alignment(model, idx))


class SharedLawFollower(HerdFollower):
    """:class:`HerdFollower` for the shared interaction law (``kind: schwager2007_shared``):
    u_k^{τ+1} = a_A(k) u_k^τ + Σ_{j≠k, d<r} F_A(k)(d_kj) e_kj + g_A(k)(p_k) + w_k, the
    neighbours j being the other active robots (same rate handling as the pairwise law)."""

    def __init__(self, model, assignment: list[str], robots: list[str] | None = None,
                 noise: bool = False, seed=None):
        self.model = robot_shared_model(model, assignment, robots)
        self.robots = list(self.model.agents)
        self.dt = float(model.dt)
        self.damping = self.model.damping
        self.noise = bool(noise)
        self.noise_source = noise_for(self.model, seed)
        self.noise_gain = np.ones(len(self.robots))
        self.place_share = np.zeros(len(self.robots))
        self.in_herd = np.ones(len(self.robots), dtype=bool)

    def drift(self, positions: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """Σ_j F(d) e + g for every robot; inactive robots (NaN, stale) exert nothing."""
        p = np.asarray(positions, dtype=float).reshape(-1, 2)
        active = np.ones(len(p), bool) if active is None else np.asarray(active, bool)
        active = active & np.isfinite(p).all(-1)
        p_active = np.where(active[:, None], p, np.nan)
        return self.model.interaction(p_active) + self.environment(p, active)


def follower_for(model, assignment: list[str], robots: list[str] | None = None,
                 noise: bool = False, seed=None) -> HerdFollower:
    """The follower for the model's law (pairwise :class:`HerdModel` or shared)."""
    from herd_ros.model.shared_law import SharedLawModel
    cls = SharedLawFollower if isinstance(model, SharedLawModel) else HerdFollower
    return cls(model, assignment, robots, noise=noise, seed=seed)


def shared_model_from_parameter_matrix(theta: np.ndarray, agents: list[str], dt: float, grid,
                                       radius: float, profile_size: int,
                                       noise_cov: np.ndarray | None = None):
    """A shared-law model from the estimator's parameter matrix (N, 1 + B + 2K): rows
    [damping, profile_1..B, field_u.., field_v..] on every centre of ``grid``, the profile
    :meth:`~herd_ros.model.shared_law.DistanceProfile.even` over ``radius`` with B terms."""
    from herd_ros.model.rbf_field import RbfBasis
    from herd_ros.model.shared_law import DistanceProfile, SharedLawModel
    theta = np.asarray(theta, dtype=float)
    n, B = len(agents), int(profile_size)
    basis = RbfBasis.from_grid(grid)
    k = basis.size
    width = 1 + B + 2 * k
    if theta.shape != (n, width):
        got = ' x '.join(str(d) for d in theta.shape)
        raise HerdInputError(f'/herd/model/params: expected {n} agents x {width} parameters '
                             f'(1 + {B} profile + 2·{k} field, shared law), got {got}')
    if not np.isfinite(theta).all():
        raise HerdInputError('/herd/model/params: parameters contain NaN or inf')
    return SharedLawModel(
        agents=list(agents), dt=float(dt), profile=DistanceProfile.even(float(radius), B),
        damping=theta[:, 0], profile_coef=theta[:, 1:1 + B], bases=[basis] * n,
        field_u=[theta[i, 1 + B:1 + B + k] for i in range(n)],
        field_v=[theta[i, 1 + B + k:] for i in range(n)],
        noise_cov=np.zeros((n, 2, 2)) if noise_cov is None else noise_cov)
