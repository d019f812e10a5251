"""Each robot's noise matched to its animal's observed speed, live (issue 30: the robots
move like their animals).

The law's noise w_i ~ N(0, Q_i) (or its stop-and-go regimes) is estimated from one-step
residuals of the track, and those carry the collar's error: a position error e enters the
velocity as (e_{τ+1} − e_τ)/Δt, which cancels along the animal's path but, drawn afresh
each step as the robots draw their noise, integrates. On duty-cycled cattle collars the
robots driven by it moved 55–70 % faster than their animals. Offline,
:mod:`herd_ros.simulation.pace_calibration` corrects the law by simulated moments on the
training data; live there is no training run to simulate, but the fleet is one: the
controller compares each robot's speed with its animal's over the same herd ticks and
corrects the factor s_k on the robot's noise standard deviation — the method of
simulated moments (McFadden 1989) with the robots as the simulation, one moment per robot:

    v_A = Σ λ^age ‖p_A(t) − p_A(t − L)‖ / L              (the animal, from /herd/poses)
    v_k = Σ λ^age ‖p_k(t) − p_k(t − L)‖ / (L s̄_k)        (its robot, per unit factor)
    s_k ← clip(v_A / v_k, s_k / 1.5, 1.5 s_k)                (P1)

over the ticks at which the animal was seen at both ends and the robot followed its law
(the robot is seen like its animal; while it waits it escorts its animal or holds still,
:mod:`herd_ros.control.escort`, which is not the law's speed), L the model's step (the
statistics of Schwager et al. 2007 are taken at the model's step), s̄_k the factor in
force over each sample (the geometric mean of its two ends) and λ = 1 − 1/``memory``. An
animal's speed over an hour is mostly whether it walked in that hour: on the 72-hour
cattle analog the robot-to-animal speed ratio of one-hour windows ranges from 0.1 to 36
while the whole run's is 1.5–1.9. So the memory is about a day of samples (2 880), the
factor first moves after ``min_samples`` (240) and then every ``update_every`` (60)
ticks, by at most a factor 1.5, and a miss below ``deadband`` (10 %) is left alone.
Every sample, whatever factor it was drawn under, estimates the robot's speed per unit
factor when the noise sets its speed; where a field, a pull or a neighbour carries part
of it (v = c + d s), (P1) is the fixed-point iteration s ← v_A / (c/s + d), which
converges to c + d s = v_A (its slope there is c / v_A < 1) when c < v_A, and sinks to
the floor when the drift alone outruns the animal. A version
with one-hour windows and no memory let the factors wander from 0.4 to 2.

Plain numpy; no ROS. The controller's mode ``herd_model`` feeds it
(:mod:`herd_ros.nodes.herd_model_mode`, parameter ``match_pace``).
"""
from __future__ import annotations

from collections import deque

import numpy as np

#: the samples' memory (e-folding, in samples): about a day of a 30 s herd clock, so
#: that the comparison spans an animal's rests and walks
MEMORY = 2880
#: samples before a robot's factor first moves, and ticks between corrections
MIN_SAMPLES = 240
UPDATE_EVERY = 60
#: a miss below this (relative) is left alone
DEADBAND = 0.10
#: the largest correction per update (a factor of 1.5)
MAX_STEP = float(np.log(1.5))
#: the range a factor is kept in
BOUNDS = (0.05, 3.0)


class PaceMatch:
    """The noise factors of R robots, each matched to its animal's speed at lag ``lag_s``
    (module docstring). Feed it every herd tick with :meth:`observe`; read
    :attr:`factors`."""

    def __init__(self, n_robots: int, lag_s: float, *, memory: float = MEMORY,
                 min_samples: int = MIN_SAMPLES, update_every: int = UPDATE_EVERY,
                 deadband: float = DEADBAND, bounds=BOUNDS):
        if not lag_s > 0:
            raise ValueError(f'lag_s must be positive, got {lag_s}')
        self.n = int(n_robots)
        self.lag = float(lag_s)
        self.keep = 1.0 - 1.0 / float(memory)
        self.min_samples = int(min_samples)
        self.update_every = int(update_every)
        self.deadband = float(np.log1p(deadband))
        self.bounds = (float(bounds[0]), float(bounds[1]))
        self.factors = np.ones(self.n)
        self.updates = 0
        self.history: list[tuple[float, np.ndarray]] = []    # (tick, factors) per change
        self._ticks = deque()            # (t, animal (R, 2), robot t (R,), robot (R, 2), s)
        self._animal = np.zeros(self.n)  # forgetful sums of the animal's speeds
        self._robot = np.zeros(self.n)   # ... and of its robot's, per unit factor
        self.samples = np.zeros(self.n, np.int64)
        self._since = 0

    def observe(self, t: float, animal_xy, robot_t, robot_xy) -> bool:
        """Take one herd tick at ``t`` (s): each robot's animal's position (R, 2; NaN where
        the animal has no pose), each robot's position (R, 2) and the time it was measured
        (R,). Returns whether the factors changed."""
        # copies: the caller's arrays (a node's latest odometry) change under us
        a = np.array(animal_xy, dtype=float).reshape(self.n, 2)
        rt = np.array(robot_t, dtype=float).reshape(self.n)
        r = np.array(robot_xy, dtype=float).reshape(self.n, 2)
        t = float(t)
        if self._ticks and t <= self._ticks[-1][0]:
            return False                            # a repeated or older tick
        self._ticks.append((t, a, rt, r, self.factors.copy()))
        # the tick L before this one (within half a tick of the clock's own step)
        while len(self._ticks) > 2 and self._ticks[1][0] <= t - self.lag + 1e-9:
            self._ticks.popleft()
        t0, a0, rt0, r0, s0 = self._ticks[0]
        step = t - self._ticks[-2][0] if len(self._ticks) >= 2 else np.inf
        if abs((t - t0) - self.lag) <= 0.5 * step + 1e-9 and t > t0:
            va = np.hypot(*(a - a0).T) / (t - t0)
            dr = rt - rt0
            with np.errstate(invalid='ignore', divide='ignore'):
                vr = np.hypot(*(r - r0).T) / dr / np.sqrt(s0 * self.factors)
            ok = np.isfinite(va) & np.isfinite(vr) & (dr > 0)
            self._animal[ok] = self.keep * self._animal[ok] + va[ok]
            self._robot[ok] = self.keep * self._robot[ok] + vr[ok]
            self.samples[ok] += 1
        self._since += 1
        if self._since < self.update_every:
            return False
        self._since = 0
        ready = (self.samples >= self.min_samples) & (self._animal > 0) & (self._robot > 0)
        if not ready.any():
            return False
        with np.errstate(divide='ignore', invalid='ignore'):
            miss = np.log(self.factors * self._robot / self._animal)    # > 0: too fast
        move = ready & (np.abs(miss) > self.deadband)
        step = np.clip(np.where(move, miss, 0.0), -MAX_STEP, MAX_STEP)
        new = np.clip(self.factors * np.exp(-step), *self.bounds)
        changed = bool((new != self.factors).any())
        self.factors = new
        if changed:
            self.updates += 1
            self.history.append((t, self.factors.copy()))
        return changed
