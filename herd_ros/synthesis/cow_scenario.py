"""A realistic synthetic cattle herd in a fenced paddock — deliberately *not* a Schwager herd.

The herd model of Schwager et al. (2007) is linear in its parameters; real cows are not. This
simulator produces herds with the structure seen in cattle GPS-collar data, for demos, for the
ingest/fit pipeline and for tests that must not be answered by the model class itself.

Behaviours modelled (figures are typical values reported in cattle GPS-collar and behaviour
studies, used as plausible defaults, not fitted to one data set):

* **Behaviour states** per cow: grazing, walking, resting (lying or standing). Grazing and
  resting alternate as a continuous-time Markov chain whose rates depend on the local solar
  time of day: grazing peaks after dawn (~07 h) and in the late afternoon (~18 h), resting
  dominates the midday heat and part of the night. Typical daily budget of cattle: roughly
  40-55 % grazing, 30-40 % resting, 5-10 % walking. The defaults give, over whole days,
  about 50-55 % grazing, 35-45 % resting and 5-9 % walking (herd synchrony makes single
  days vary by ±5 %).
* **Speeds**: grazing ~0.03-0.15 m/s (median ~0.07) in step-stop fashion with a meandering
  heading (heading random walk, ~0.35 rad/√s, plus occasional sharp turns); walking
  ~0.6-1.2 m/s on a persistent heading towards a goal; resting 0 m/s.
* **Goals**: water trough(s), visited every ~3-6 h per cow (each cow has its own interval; it
  stands drinking 2-7 min and then grazes); shade (trees) sought for resting in the heat of the
  day (around 11-16 h solar time); new grazing patches 40-150 m away; and the herd itself when
  a cow finds itself more than ~40 m from the others.
* **Fence**: the paddock polygon is never left. A step that would cross the fence slides to the
  fence and is nudged 1 m inside; a grazing cow that meets the fence reflects its heading.
* **Social behaviour**: state synchronisation (the rate of switching into a state grows with
  the fraction of the other cows already in it), following (when a cow sets off walking, the
  others join with a rate that grows with their follower tendency and walk to the same goal),
  cohesion (a grazing cow drifts back towards the others beyond a personal radius of 10-30 m),
  short-range repulsion below 3 m and a hard minimum spacing of 2 m, so cows never coincide.
* **Individual differences**: per-cow speed factor (0.75-1.25), leadership rank (leaders
  initiate relocations and water trips, followers join), cohesion radius, drinking interval.

Time of day is local mean solar time, ``(t + lon/15 h) mod 24 h`` with ``t`` in seconds since
the epoch (UTC) and ``lon`` the paddock datum's longitude, so ``start_time`` may be an epoch
stamp. With the default datum (lon -108.79°) ``start_time=0`` is 16:45 solar time.

The simulation is a Python loop over time steps with every per-cow quantity a numpy array, and
is deterministic for a seed (one ``numpy.random.Generator``, draws in a fixed order).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from matplotlib.path import Path

from herd_ros.errors import HerdInputError
from herd_ros.trajectory import HerdTrajectory

#: Datum (lat °, lon °, alt m) of the default paddock: the example of doc/formats.md.
DEFAULT_DATUM = (27.0153, -108.7937, 0.0)

#: Behaviour state codes stored in ``HerdTrajectory.meta['state']``.
GRAZING, WALKING, RESTING = 0, 1, 2
STATE_NAMES = ('grazing', 'walking', 'resting')

# Goal kinds of a walking cow (``meta['walk_goal']``).
_GOAL_NONE, _GOAL_WATER, _GOAL_SHADE, _GOAL_PATCH, _GOAL_HERD = 0, 1, 2, 3, 4
WALK_GOAL_NAMES = ('none', 'water', 'shade', 'patch', 'herd')

# --- behaviour parameters (typical values, see the module docstring) ---------------------------
GRAZE_SPEED_MEDIAN = 0.07      # m/s, median grazing speed while stepping
GRAZE_LOG_SPEED_STD = 0.45     # std of log grazing speed (0.07·e^±1.5σ ≈ 0.035-0.14 m/s)
GRAZE_SPEED_TAU = 30.0         # s, correlation time of the grazing speed
GRAZE_PAUSE_MEAN = 8.0         # s, mean standing pause between grazing steps
GRAZE_MOVE_MEAN = 20.0         # s, mean stepping period while grazing
GRAZE_TURN_STD = 0.35          # rad/√s, heading random walk while grazing
GRAZE_SHARP_TURN_RATE = 1 / 60.0  # 1/s, rate of a new random grazing heading
WALK_SPEED = 0.85              # m/s, walking speed of a cow with speed factor 1
WALK_HEADING_STD = 0.08        # rad, heading noise while walking
WALK_TIMEOUT = 900.0           # s, a walk that has not arrived by then turns into grazing
BOUT_TIME = 25 * 60.0          # s, time scale of grazing/resting bouts (1/k0)
SYNC_GAIN = 3.0                # rate multiplier per unit fraction of others in the target state
FOLLOW_RATE = 1 / 20.0         # 1/s, rate of joining walkers (× follower tendency × fraction)
PATCH_RATE = 1 / 3600.0        # 1/s, rate of starting a relocation walk (× 2·leadership)
PATCH_DISTANCE = (40.0, 150.0)  # m, distance of a new grazing patch from the herd
DRINK_INTERVAL = (3 * 3600.0, 6 * 3600.0)  # s, per-cow interval between water visits
THIRST_RATE = 1 / 300.0        # 1/s, rate of leaving for water once the interval is over
DRINK_DURATION = (120.0, 420.0)  # s, standing at the trough
ISOLATION_DISTANCE = 40.0      # m, beyond this from the others' centroid a cow walks back
ISOLATION_RATE = 1 / 30.0      # 1/s
REJOIN_DISTANCE = 15.0         # m, a cow walking back to the herd stops here
COHESION_RADIUS = (10.0, 30.0)  # m, personal radius (followers small, leaders large)
COHESION_GAIN = 0.01           # 1/s, drift speed per metre beyond the radius
COHESION_MAX = 0.12            # m/s
REPULSION_RANGE = 3.0          # m, soft repulsion below this distance
REPULSION_GAIN = 0.3           # 1/s
MIN_SPACING = 2.0              # m, hard minimum distance between cows
FENCE_MARGIN = 1.0             # m, cows are kept this far inside the fence
ARRIVAL_RADIUS = 3.0           # m
GOAL_SCATTER = 5.0             # m, std of a cow's personal offset around a goal point


def _default_fence():
    return np.array([[-200.0, -150.0], [200.0, -150.0], [200.0, 150.0], [-200.0, 150.0]])


def _default_water():
    return np.array([[180.0, -130.0]])


def _default_shade():
    return np.array([[-130.0, 95.0], [-105.0, 110.0], [60.0, 40.0]])


@dataclass
class Paddock:
    """A fenced paddock in the local ENU frame (metres, x east, y north) about ``datum``.

    Attributes:
        fence: (K, 3+) polygon vertices, either orientation (stored counter-clockwise).
        water: (W, 2) water troughs, W ≥ 1, inside the fence.
        shade: (S, 2) shade trees, S ≥ 0, inside the fence.
        datum: (lat °, lon °, alt m) of the frame's origin; its longitude sets solar time.

    The default is a 400 m × 300 m paddock centred on the datum with a trough near the
    south-east corner, a clump of two trees in the north-west and one tree near the middle.
    """

    fence: np.ndarray = field(default_factory=_default_fence)
    water: np.ndarray = field(default_factory=_default_water)
    shade: np.ndarray = field(default_factory=_default_shade)
    datum: tuple = DEFAULT_DATUM

    def __post_init__(self):
        fence = np.asarray(self.fence, dtype=float)
        if fence.ndim != 2 or fence.shape[1] != 2 or len(fence) < 3:
            raise HerdInputError(f'paddock fence must be a (K, 2) array of K >= 3 vertices, '
                                 f'got shape {fence.shape}')
        if not np.isfinite(fence).all():
            raise HerdInputError('paddock fence has a non-finite vertex')
        if _signed_area(fence) < 0:
            fence = fence[::-1].copy()
        if _signed_area(fence) < 100.0:
            raise HerdInputError('paddock fence encloses less than 100 m², or is degenerate')
        self.fence = fence
        self.water = self._points_inside(self.water, 'water', need=1)
        self.shade = self._points_inside(self.shade, 'shade', need=0)
        if len(self.datum) not in (2, 3) or not np.isfinite(self.datum).all():
            raise HerdInputError(f'paddock datum must be (lat, lon[, alt]), got {self.datum!r}')
        self.datum = tuple(float(v) for v in self.datum) + ((0.0,) if len(self.datum) == 2 else ())

    def _points_inside(self, points, name, need):
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        if len(pts) < need:
            raise HerdInputError(f'paddock needs at least {need} {name} point(s)')
        if len(pts) and not (self.contains(pts).all() and np.isfinite(pts).all()):
            raise HerdInputError(f'paddock {name} points must lie inside the fence')
        return pts

    @property
    def area(self) -> float:
        """Enclosed area (m²)."""
        return _signed_area(self.fence)

    @property
    def path(self) -> Path:
        """The fence as a closed matplotlib Path."""
        return Path(np.vstack([self.fence, self.fence[:1]]), closed=True)

    def contains(self, points) -> np.ndarray:
        """(M,) bool: which of the (M, 2) points lie strictly inside the fence."""
        return self.path.contains_points(np.asarray(points, dtype=float).reshape(-1, 2))


def _signed_area(poly):
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


class _Fence:
    """Edge geometry of a counter-clockwise polygon for inside and nearest-point queries."""

    def __init__(self, paddock: Paddock):
        self.path = paddock.path
        self.a = paddock.fence
        self.d = np.roll(paddock.fence, -1, axis=0) - self.a          # (K, 2) edge vectors
        self.dd = (self.d ** 2).sum(axis=1)                            # (K,)
        self.normal = np.stack([-self.d[:, 1], self.d[:, 0]], axis=1) / np.sqrt(self.dd)[:, None]
        self.offset = (self.normal * self.a).sum(axis=1)               # inward: n·p − offset > 0
        self.angle = np.arctan2(self.d[:, 1], self.d[:, 0])            # (K,) edge directions
        turn = self.d[:, 0] * np.roll(self.d[:, 1], -1) - self.d[:, 1] * np.roll(self.d[:, 0], -1)
        self.convex = bool((turn >= 0).all())

    def nearest(self, p):
        """Nearest fence point q (M, 2), distance (M,) and edge index (M,) of points p (M, 2)."""
        w = p[:, None, :] - self.a[None]
        s = np.clip((w * self.d).sum(-1) / self.dd, 0.0, 1.0)
        q = self.a[None] + s[..., None] * self.d[None]
        dist2 = ((p[:, None, :] - q) ** 2).sum(-1)
        k = dist2.argmin(axis=1)
        rows = np.arange(len(p))
        return q[rows, k], np.sqrt(dist2[rows, k]), k

    def inside(self, p, margin=0.0):
        """(M,) bool: points inside the fence and at least ``margin`` metres from it."""
        if self.convex:   # half-plane test, exact for convex polygons
            return (p @ self.normal.T - self.offset).min(axis=1) >= max(margin, 1e-12)
        ok = self.path.contains_points(p)
        if margin > 0:
            ok &= self.nearest(p)[1] >= margin
        return ok


def _circular_bump(hour, centre, width):
    d = (hour - centre + 12.0) % 24.0 - 12.0
    return np.exp(-0.5 * (d / width) ** 2)


def grazing_propensity(hour):
    """Share of grazing in the grazing/resting alternation at solar ``hour`` (0-24).

    Two bumps, after dawn (07 h) and in the late afternoon (18 h), over a base of 0.255 —
    the bimodal daily grazing pattern of cattle.
    """
    p = 0.255 + 0.65 * (_circular_bump(hour, 7.0, 2.0) + _circular_bump(hour, 18.0, 2.2))
    return np.clip(p, 0.08, 0.92)


def heat_of_day(hour):
    """0-1 heat load at solar ``hour``: peaks at 13:30, about zero before 10 h and after 17 h."""
    return _circular_bump(hour, 13.5, 1.6)


def solar_hour(t, lon_deg):
    """Local mean solar hour (0-24) of epoch seconds ``t`` at longitude ``lon_deg``."""
    return ((np.asarray(t, dtype=float) + lon_deg / 15.0 * 3600.0) % 86400.0) / 3600.0


def simulate_cow_herd(n_cows: int = 3, duration_s: float = 3600.0, dt: float = 1.0,
                      seed: int = 0, paddock: Paddock | None = None,
                      start_time: float = 0.0, agents: list[str] | None = None
                      ) -> HerdTrajectory:
    """Simulate a cattle herd in a paddock (see the module docstring for the behaviours).

    Args:
        n_cows: herd size (ignored when ``agents`` is given).
        duration_s: length of the run (s); ``T = round(duration_s / dt)`` samples.
        dt: sample and integration step (s), 0 < dt ≤ 10.
        seed: seed of the random generator; equal seeds give equal herds.
        paddock: the paddock; ``Paddock()`` by default (400 m × 300 m about DEFAULT_DATUM).
        start_time: time of the first sample, epoch seconds (UTC); sets the time of day.
        agents: agent ids; default ``cow_1 … cow_N``.

    Returns:
        HerdTrajectory with ``times`` (T,) = start_time + k·dt, ``positions`` (T, N, 2) metres
        ENU about ``paddock.datum``, and ``meta``: ``state`` (T, N) int8 behaviour during the
        step k → k+1 (codes GRAZING, WALKING, RESTING; names in ``state_names``), ``datum``,
        ``paddock``, ``seed``, ``scenario='cows'``.

    Raises:
        HerdInputError: on a non-positive herd size, duration or step, or a paddock too small
            for the herd.
    """
    paddock = Paddock() if paddock is None else paddock
    if agents is not None:
        agents = [str(a) for a in agents]
        if len(set(agents)) != len(agents):
            raise HerdInputError('cow scenario: agent ids must be unique')
        n_cows = len(agents)
    if int(n_cows) != n_cows or n_cows < 1:
        raise HerdInputError(f'cow scenario: n_cows must be a positive integer, got {n_cows!r}')
    n = int(n_cows)
    agents = agents or [f'cow_{i + 1}' for i in range(n)]
    if not (np.isfinite(dt) and 0 < dt <= 10.0):
        raise HerdInputError(f'cow scenario: dt must be in (0, 10] s, got {dt!r}')
    n_steps = int(round(duration_s / dt)) if np.isfinite(duration_s) else 0
    if n_steps < 2:
        raise HerdInputError(f'cow scenario: duration_s={duration_s!r} gives fewer than two '
                             f'samples at dt={dt!r}')
    if paddock.area < 50.0 * n:
        raise HerdInputError(f'cow scenario: a {paddock.area:.0f} m² paddock is too small for '
                             f'{n} cows (needs 50 m² per cow)')

    rng = np.random.default_rng(seed)
    fence = _Fence(paddock)
    times = start_time + dt * np.arange(n_steps)
    hours = solar_hour(times, paddock.datum[1])

    # --- individual differences ---------------------------------------------------------------
    speed_factor = np.clip(rng.normal(1.0, 0.12, n), 0.75, 1.25)
    leadership = (rng.permutation(n) + 0.5) / n                      # (0, 1), one leader
    walk_speed = np.clip(WALK_SPEED * speed_factor, 0.6, 1.2)
    cohesion_radius = COHESION_RADIUS[0] + (COHESION_RADIUS[1] - COHESION_RADIUS[0]) * leadership
    drink_interval = rng.uniform(*DRINK_INTERVAL, n)
    since_drink = rng.uniform(0.0, 1.0, n) * drink_interval

    # --- initial herd -----------------------------------------------------------------------
    pos = _initial_positions(n, fence, paddock, rng)
    p_g0 = grazing_propensity(hours[0])
    herd_grazes = rng.random() < p_g0
    agree = rng.random(n) < 0.85
    state = np.where(agree == herd_grazes, GRAZING, RESTING).astype(np.int8)
    heading = rng.uniform(-np.pi, np.pi, n)
    log_speed = np.log(GRAZE_SPEED_MEDIAN) + GRAZE_LOG_SPEED_STD * rng.normal(size=n)
    paused = rng.random(n) < GRAZE_PAUSE_MEAN / (GRAZE_PAUSE_MEAN + GRAZE_MOVE_MEAN)
    goal_kind = np.zeros(n, dtype=np.int8)
    goal = np.zeros((n, 2))          # where each walking cow heads: its goal + own offset
    goal_base = np.zeros((n, 2))     # the shared goal point (water, shade, patch, herd)
    walk_started = np.zeros(n)
    drink_until = np.full(n, -np.inf)

    # --- per-step random numbers, drawn up front -------------------------------------------
    u_event = rng.random((n_steps, n))
    u_which = rng.random((n_steps, n))
    u_pause = rng.random((n_steps, n))
    u_turn = rng.random((n_steps, n))
    z_turn = rng.normal(size=(n_steps, n))
    z_speed = rng.normal(size=(n_steps, n))
    z_walk = rng.normal(size=(n_steps, n, 2))   # heading noise, speed noise

    rho_speed = np.exp(-dt / GRAZE_SPEED_TAU)
    speed_innov = GRAZE_LOG_SPEED_STD * np.sqrt(1.0 - rho_speed ** 2)
    p_pause_start = 1.0 - np.exp(-dt / GRAZE_MOVE_MEAN)
    p_pause_end = 1.0 - np.exp(-dt / GRAZE_PAUSE_MEAN)
    p_sharp_turn = 1.0 - np.exp(-dt * GRAZE_SHARP_TURN_RATE)
    turn_std = GRAZE_TURN_STD * np.sqrt(dt)
    log_median = np.log(GRAZE_SPEED_MEDIAN)
    others = max(n - 1, 1)
    has_shade = len(paddock.shade) > 0
    # time-of-day rates for every step (1/s)
    p_graze = grazing_propensity(hours)
    heat = heat_of_day(hours)
    rate_to_rest = (1.0 - p_graze) / BOUT_TIME
    rate_to_graze = p_graze / BOUT_TIME
    rate_patch = PATCH_RATE * p_graze
    patch_weight = 2.0 * leadership
    follow_weight = FOLLOW_RATE * (1.0 - leadership)
    arrive_radius = np.maximum(ARRIVAL_RADIUS, 0.5 * walk_speed * dt)
    unit = np.empty((n, 2))
    rates = np.empty((n, 6))

    positions = np.empty((n_steps, n, 2))
    states = np.empty((n_steps, n), dtype=np.int8)
    goals = np.empty((n_steps, n), dtype=np.int8)
    for k in range(n_steps):
        t = times[k]
        positions[k] = pos

        # herd context: centroid of the others, fractions of the others per state
        centroid_others = (pos.sum(axis=0) - pos) / others if n > 1 else pos.copy()
        to_herd = centroid_others - pos
        dist_herd = np.hypot(to_herd[:, 0], to_herd[:, 1])

        # finished drinking -> graze
        drinking = drink_until > t
        done = ~drinking & (drink_until > -np.inf)
        if done.any():
            state[done] = GRAZING
            drink_until[done] = -np.inf
        is_graze = state == GRAZING
        is_rest = state == RESTING
        is_walk = state == WALKING
        lead_walk = is_walk & (goal_kind != _GOAL_HERD)

        # --- competing events (rates 1/s), only for cows free to change state ----------------
        free = ~(is_walk | drinking)
        if free.any():
            counts = np.bincount(state, minlength=3)
            f_graze = (counts[GRAZING] - is_graze) / others
            f_rest = (counts[RESTING] - is_rest) / others
            f_walk = (lead_walk.sum() - lead_walk) / others
            graze_free = is_graze & free
            rest_free = is_rest & free
            rates[:, 0] = graze_free * rate_to_rest[k] * (1 + SYNC_GAIN * f_rest)
            rates[:, 1] = rest_free * rate_to_graze[k] * (1 + SYNC_GAIN * f_graze)
            rates[:, 2] = graze_free * rate_patch[k] * patch_weight
            rates[:, 3] = (free & (since_drink > drink_interval)) * THIRST_RATE
            rates[:, 4] = free * follow_weight * f_walk * np.where(is_rest, 0.5, 1.0)
            rates[:, 5] = (free & (dist_herd > ISOLATION_DISTANCE)) * ISOLATION_RATE
            cum = np.cumsum(rates, axis=1)
            total_rate = cum[:, -1]
            fires = u_event[k] < -np.expm1(-total_rate * dt)
            if fires.any():
                event = (cum < (u_which[k] * total_rate)[:, None]).sum(axis=1)
                event = np.where(fires, np.minimum(event, 5), -1)
                _apply_events(event, state, goal_kind, goal, goal_base, walk_started, t, heat[k],
                              has_shade, pos, centroid_others, lead_walk, leadership,
                              paddock, fence, rng)
                is_graze = state == GRAZING
                is_walk = state == WALKING

        # --- velocities ----------------------------------------------------------------------
        # grazing: step-stop, meandering heading, cohesion drift
        paused = np.where(paused, u_pause[k] >= p_pause_end, u_pause[k] < p_pause_start)
        log_speed = log_median + rho_speed * (log_speed - log_median) + speed_innov * z_speed[k]
        heading = np.where(u_turn[k] < p_sharp_turn, (u_turn[k] / p_sharp_turn - 0.5) * 2 * np.pi,
                           heading + turn_std * z_turn[k])
        moving_graze = is_graze & ~paused
        step_speed = np.minimum(np.exp(log_speed), 0.2) * speed_factor * moving_graze
        pull = np.clip(COHESION_GAIN * (dist_herd - cohesion_radius), 0.0, COHESION_MAX)
        pull *= moving_graze / np.maximum(dist_herd, 1e-9)
        unit[:, 0] = np.cos(heading)
        unit[:, 1] = np.sin(heading)
        vel = step_speed[:, None] * unit + pull[:, None] * to_herd
        # walking: persistent heading to the goal (+ personal offset), or back to the herd
        if is_walk.any():
            herd_walk = is_walk & (goal_kind == _GOAL_HERD)
            goal[herd_walk] = goal_base[herd_walk] = centroid_others[herd_walk]
            to_goal = goal - pos
            dist_goal = np.hypot(to_goal[:, 0], to_goal[:, 1])
            arrived = is_walk & ((dist_goal < np.where(herd_walk, REJOIN_DISTANCE, arrive_radius))
                                 | (t - walk_started > WALK_TIMEOUT))
            if arrived.any():
                _arrive(arrived, state, goal_kind, drink_until, since_drink, t, rng)
                is_walk = state == WALKING
            bearing = np.arctan2(to_goal[:, 1], to_goal[:, 0]) + WALK_HEADING_STD * z_walk[k, :, 0]
            speed = np.minimum(walk_speed * (1 + 0.05 * z_walk[k, :, 1]), dist_goal / dt)
            walk_vel = speed[:, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])
            vel[is_walk] = walk_vel[is_walk]
            heading = np.where(is_walk, bearing, heading)
            moving = moving_graze | is_walk
        else:
            moving = moving_graze
        # soft short-range repulsion for moving cows
        if n > 1:
            vel += _repulsion(pos) * moving[:, None]

        new = _separate(pos + vel * dt)
        new, hit_edge = _keep_inside(new, pos, fence)
        if hit_edge is not None:   # slid along the fence: grazing cows reflect their heading
            new, _ = _keep_inside(_separate(new), pos, fence)
            reflect = (hit_edge >= 0) & is_graze
            heading = np.where(reflect, 2 * fence.angle[np.maximum(hit_edge, 0)] - heading,
                               heading)
        states[k] = state
        goals[k] = goal_kind
        pos = new
        since_drink += dt

    meta = {'state': states, 'state_names': STATE_NAMES, 'walk_goal': goals,
            'walk_goal_names': WALK_GOAL_NAMES, 'datum': paddock.datum,
            'paddock': paddock, 'seed': seed, 'scenario': 'cows',
            'speed_factor': speed_factor, 'leadership': leadership}
    return HerdTrajectory(times, list(agents), positions, None, meta)


def _initial_positions(n, fence, paddock, rng):
    """A tight group (5 m spacing, jittered) about a random centre ≥ 30 m inside the fence."""
    side = int(np.ceil(np.sqrt(n)))
    gx, gy = np.meshgrid(np.arange(side), np.arange(side))
    grid = np.column_stack([gx.ravel(), gy.ravel()])[:n] * 5.0
    grid = grid - grid.mean(axis=0) + rng.uniform(-1.0, 1.0, (n, 2))
    lo, hi = paddock.fence.min(axis=0), paddock.fence.max(axis=0)
    for _ in range(200):
        centre = rng.uniform(lo, hi)
        candidate = centre + grid
        if fence.inside(candidate, margin=max(FENCE_MARGIN, min(30.0, 0.1 * (hi - lo).min()))
                        ).all():
            return candidate
    # small or odd paddocks: shrink the group towards a water point until it fits
    for scale in np.linspace(1.0, 0.0, 21):
        candidate = paddock.water[0] + grid * scale
        if fence.inside(candidate, margin=FENCE_MARGIN).all():
            return candidate
    raise HerdInputError('cow scenario: could not place the herd inside the paddock')


def _apply_events(event, state, goal_kind, goal, goal_base, walk_started, t, heat, has_shade,
                  pos, centroid_others, lead_walk, leadership, paddock, fence, rng):
    """Apply fired events in place. Codes: 0 rest (or walk to shade in the heat), 1 graze,
    2 walk to a new patch, 3 walk to water, 4 follow the leading walker, 5 walk to the herd."""
    walk = dict(state=state, goal_kind=goal_kind, goal=goal, goal_base=goal_base,
                walk_started=walk_started, t=t, fence=fence, rng=rng)
    to_rest = event == 0
    if to_rest.any() and has_shade:
        to_shade = to_rest & (rng.random(len(event)) < min(0.95, 1.2 * heat))
        if to_shade.any():
            _start_walk(to_shade, _GOAL_SHADE, _nearest(pos[to_shade], paddock.shade), **walk)
            to_rest &= ~to_shade
    state[to_rest] = RESTING
    state[event == 1] = GRAZING
    patch = event == 2
    if patch.any():
        _start_walk(patch, _GOAL_PATCH, _patch_goals(centroid_others[patch], fence, paddock, rng),
                    **walk)
    water = event == 3
    if water.any():
        _start_walk(water, _GOAL_WATER, _nearest(pos[water], paddock.water), **walk)
    follow = (event == 4) & lead_walk.any()
    if follow.any():
        leader = int(np.argmax(np.where(lead_walk, leadership, -np.inf)))
        _start_walk(follow, goal_kind[leader], goal_base[leader], **walk)
    back = event == 5
    if back.any():
        _start_walk(back, _GOAL_HERD, centroid_others[back], scatter=False, **walk)


def _start_walk(mask, kind, target, *, state, goal_kind, goal, goal_base, walk_started, t,
                fence, rng, scatter=True):
    """Start walks of the ``mask`` cows to ``target`` (shared goal point(s)), each heading for
    its own spot around it (std GOAL_SCATTER, kept ≥ 2 m inside the fence) so that the herd
    arrives as a group."""
    m = int(mask.sum())
    state[mask] = WALKING
    goal_kind[mask] = kind
    walk_started[mask] = t
    goal_base[mask] = target
    spot = goal_base[mask]
    if scatter:
        jittered = spot + rng.normal(0.0, GOAL_SCATTER, (m, 2))
        ok = fence.inside(jittered, margin=2.0)
        spot = np.where(ok[:, None], jittered, spot)
    goal[mask] = spot


def _arrive(arrived, state, goal_kind, drink_until, since_drink, t, rng):
    """End the walks of ``arrived`` cows: drink at water, rest in shade, otherwise graze."""
    at_water = arrived & (goal_kind == _GOAL_WATER)
    at_shade = arrived & (goal_kind == _GOAL_SHADE)
    state[arrived] = GRAZING
    state[at_shade | at_water] = RESTING
    drink_until[at_water] = t + rng.uniform(*DRINK_DURATION, int(at_water.sum()))
    since_drink[at_water] = 0.0
    goal_kind[arrived] = _GOAL_NONE


def _nearest(points, targets):
    d2 = ((points[:, None, :] - targets[None]) ** 2).sum(-1)
    return targets[d2.argmin(axis=1)].copy()


def _patch_goals(centres, fence, paddock, rng, tries=24):
    """New grazing spots 40-150 m from each centre, ≥ 10 m inside the fence."""
    m = len(centres)
    r = rng.uniform(*PATCH_DISTANCE, (m, tries))
    a = rng.uniform(-np.pi, np.pi, (m, tries))
    cand = centres[:, None, :] + r[..., None] * np.stack([np.cos(a), np.sin(a)], axis=-1)
    ok = fence.inside(cand.reshape(-1, 2), margin=10.0).reshape(m, tries)
    pick = ok.argmax(axis=1)
    goals = cand[np.arange(m), pick]
    goals[~ok.any(axis=1)] = paddock.water[0]
    return goals


def _repulsion(pos):
    """Soft repulsion velocity (N, 2): Σ_j gain·(R − d_ij)·(p_i − p_j)/d_ij for d_ij < R."""
    diff = pos[:, None, :] - pos[None, :, :]
    d = np.hypot(diff[..., 0], diff[..., 1])
    np.fill_diagonal(d, np.inf)
    w = REPULSION_GAIN * np.clip(REPULSION_RANGE - d, 0.0, None) / np.maximum(d, 1e-9)
    return (w[..., None] * diff).sum(axis=1)


def _separate(pos):
    """Push apart every pair closer than MIN_SPACING, each cow half the overlap (one pass)."""
    n = len(pos)
    if n < 2:
        return pos
    diff = pos[:, None, :] - pos[None, :, :]
    d = np.hypot(diff[..., 0], diff[..., 1])
    np.fill_diagonal(d, np.inf)
    overlap = np.clip(MIN_SPACING - d, 0.0, None)
    if not overlap.any():
        return pos
    unit = diff / np.maximum(d, 1e-9)[..., None]
    # exactly coincident cows: separate along a fixed direction, by index order
    same = d < 1e-9
    if same.any():
        sign = np.sign(np.arange(n)[:, None] - np.arange(n)[None, :])
        unit[same] = np.column_stack([sign[same], np.zeros(int(same.sum()))])
    return pos + 0.5 * (overlap[..., None] * unit).sum(axis=1)


def _keep_inside(new, old, fence):
    """Slide steps that leave the fence (or come within FENCE_MARGIN of it) back inside.

    Returns the corrected positions and, per cow, the index of the fence edge it hit (-1 if
    none), or ``None`` when no cow came near the fence. A cow whose correction is still
    outside (a concave corner) stays put; ``old`` is inside by induction.
    """
    if fence.convex:
        slack = (new @ fence.normal.T - fence.offset).min(axis=1)
        if (slack >= FENCE_MARGIN).all():
            return new, None
    q, dist, edge = fence.nearest(new)
    bad = ~fence.path.contains_points(new) | (dist < FENCE_MARGIN)
    if not bad.any():
        return new, None
    hit = np.where(bad, edge, -1)
    new = new.copy()
    new[bad] = q[bad] + FENCE_MARGIN * fence.normal[edge[bad]]
    still = ~fence.path.contains_points(new)
    new[still] = old[still]
    return new, hit
