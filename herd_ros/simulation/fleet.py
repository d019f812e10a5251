"""The simulated fleet of the ``fleet_sim`` node, with no ROS in it (issue 26): robots
(holonomic or unicycle, :mod:`herd_ros.control.kinematics`) driven by body-frame commands,
a command watchdog, the fence as a wall, and counts of collisions.

:meth:`FleetSimulator.integrate_to` advances every robot to a time under its current
command and keeps its state at every multiple of the step period on the way (the node
publishes those, stamped with them). A robot whose last command is older than
``cmd_timeout_s`` (or that never got one) is stopped at once — a watchdog cut, not a ramp.
The fence is a wall: a step that would cross it is not taken (the robot stops, a fence
contact is counted). Obstacles are not walls: overlaps with them (and between robots) are
counted as collisions.
"""
from __future__ import annotations

import numpy as np

from herd_ros.control import kinematics as kin

#: Periods of a clock jump the fleet integrates through; a longer jump restarts its grid.
MAX_CATCH_UP = 100


class FleetSimulator:
    """The fleet of ``cfg`` (a :class:`~herd_ros.params.fleet_sim.FleetSimConfig`: robots,
    kinematics, limits, fence, obstacles, radius, rate, watchdog; read at every step, so a
    changed limit applies at once)."""

    def __init__(self, cfg):
        n = len(cfg.robots)
        self.cfg = cfg
        self.state = kin.FleetState.at_rest(cfg.initial_poses)
        self.command = np.zeros((n, 3))                  # v_x, v_y, ω (body frame)
        self.command_time = np.full(n, np.nan)           # clock seconds of the last command
        self.yaw_rate = np.zeros(n)                      # realised ω of the last step
        self.collisions = np.zeros(n, dtype=np.int64)    # onsets of overlap (obstacles, robots)
        self.fence_contacts = np.zeros(n, dtype=np.int64)
        self.stale_events = np.zeros(n, dtype=np.int64)
        self.overlap = np.zeros(n, bool)
        self._was_stale = np.ones(n, bool)
        self._last_step = None
        self._next_grid = None
        self.snapshots = []                              # (grid time, state, yaw rate)
        self.log = []                                    # lines for the node to log

    def set_command(self, k: int, now: float, command):
        """Robot ``k``'s command (v_x, v_y, ω) from ``now`` on: the fleet is first advanced
        to ``now`` under the commands it had (not applied back to the last step, nor held
        until the next one)."""
        self.integrate_to(now)
        self.command[k] = command
        self.command_time[k] = now

    def take_snapshots(self) -> list:
        """The (grid time, state, yaw rate) kept since the last call."""
        out, self.snapshots = self.snapshots, []
        return out

    def stale(self, now: float) -> np.ndarray:
        """Robots whose last command is older than ``cmd_timeout_s`` (or never came)."""
        with np.errstate(invalid='ignore'):
            return ~(now - self.command_time <= self.cfg.cmd_timeout_s)

    def integrate_to(self, now: float):
        """Advance every robot to ``now`` under its current command, keeping its state at
        every multiple of the step period 1/rate_hz on the way: the poses are published at
        those grid times, stamped with them (with rate_hz = 2/Δt the grid holds every
        herd-clock tick k·Δt, so a robot is measured at the ticks its animal is)."""
        period = 1.0 / self.cfg.rate_hz
        if now <= 0.0:                  # sim time before the first /clock: nothing yet
            return
        if (self._last_step is None or now < self._last_step - 1e-9
                or now - self._next_grid > MAX_CATCH_UP * period):
            # the first call, time going backwards (a bag replayed again) or a jump (sim
            # time starting, a replay resumed): the grid restarts at now, the robots where
            # they are (stepping the gap one period at a time would stall the node)
            if self._last_step is not None:
                self.log.append(f'clock jumped from {self._last_step:.3f} to {now:.3f} s: '
                                f'the robots hold their state across the jump')
            self._last_step = now
            self._next_grid = np.ceil(now / period - 1e-9) * period
        while self._next_grid <= now + 1e-9:
            self._advance_span(self._next_grid)
            self.snapshots.append((self._next_grid, self.state, self.yaw_rate.copy()))
            self._next_grid += period
        self._advance_span(now)

    def _advance_span(self, now: float):
        """Advance from the last integration time to ``now`` (zero command where stale: the
        watchdog)."""
        cfg = self.cfg
        if now <= self._last_step:
            return
        h = min(now - self._last_step, 5.0 / cfg.rate_hz)
        self._last_step = now
        stale = self.stale(now)
        self.stale_events += stale & ~self._was_stale
        self._was_stale = stale
        cmd = np.where(stale[:, None], 0.0, self.command)
        if h > 0:
            self.advance(cmd, stale, h)

    def advance(self, cmd, stale, h):
        """Advance the robots by ``h`` s under the commands ``cmd`` (stale ones stopped)."""
        cfg, old = self.cfg, self.state
        if cfg.kinematics == 'holonomic':
            new = kin.step_holonomic(old, cmd[:, :2], cmd[:, 2], h, cfg.max_speed, cfg.max_accel,
                                     cfg.max_yaw_rate)
        else:
            new = kin.step_unicycle(old, cmd[:, 0], cmd[:, 2], h, cfg.max_speed, cfg.max_accel,
                                    cfg.max_yaw_rate)
        new.velocity[stale] = 0.0                        # watchdog: stale commands cut the drive
        new.positions[stale] = old.positions[stale]
        if cfg.fence is not None:
            t, _ = cfg.fence.first_crossing(old.positions, new.positions)
            blocked = np.isfinite(t)
            self.fence_contacts += blocked
            new.positions[blocked] = old.positions[blocked]
            new.velocity[blocked] = 0.0
        self.yaw_rate = kin.wrap_angle(new.yaw - old.yaw) / h
        self.state = new
        overlap = np.zeros(len(cfg.robots), bool)
        if len(cfg.obstacles):
            overlap |= cfg.obstacles.collisions(new.positions, cfg.robot_radius) > 0
        d = np.sqrt(((new.positions[:, None] - new.positions[None]) ** 2).sum(-1))
        np.fill_diagonal(d, np.inf)
        overlap |= (d < 2 * cfg.robot_radius).any(axis=1)
        self.collisions += overlap & ~self.overlap
        self.overlap = overlap
