"""The fleet starts together: no robot is driven until every robot the controller owns has
reported its odometry once, or a wait has passed since the first one did.

A swarm law is a law of the whole fleet. Started on the robots heard so far — on a loaded
machine DDS discovery can match one robot's odometry seconds after another's — the law
moves a sub-swarm (cohesion towards the centroid of the robots it knows), and the fleet
then follows another trajectory than the law's from the same start: replayed offline, eight
imitation robots of which only some are driven for the first 2 s end up with a spread 1.2
times off the run that starts them all (relative AMD gap). Waiting for all
is the rule; ``startup_wait_s`` bounds it, so a robot that never reports does not hold the
others for ever (it joins when it reports, as a robot whose odometry went stale does).

Plain numpy; no ROS (the ``controller`` node keeps one gate).
"""
from __future__ import annotations

import numpy as np


class StartGate:
    """Open once every owned robot has been heard, or ``wait_s`` after the first was."""

    def __init__(self, wait_s: float):
        self.wait_s = float(wait_s)
        self.first_heard = None       # node time (s) the first owned robot was heard
        self.open = False
        self.missing_at_start = []    # indices of the owned robots not heard when it opened

    def update(self, heard_at: np.ndarray, owned: np.ndarray, now: float) -> bool:
        """Whether the fleet may move at ``now``. ``heard_at``: each robot's last odometry
        (node time, s; NaN = never), ``owned``: the robots this controller drives."""
        if self.open:
            return True
        owned = np.asarray(owned, bool)
        heard = np.isfinite(np.asarray(heard_at, dtype=float)) & owned
        if not heard.any():
            return False
        if self.first_heard is None:
            self.first_heard = float(now)
        if heard[owned].all() or now - self.first_heard >= self.wait_s:
            self.open = True
            self.missing_at_start = np.flatnonzero(owned & ~heard).tolist()
        return self.open
