"""What a control mode sees of the fleet at a tick (the controller node fills it from
odometry; every mode's ``command(state)`` reads it)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FleetObservation:
    """What a policy sees at a tick; arrays over the R observed robots (own first).

    positions (R, 2) m and yaw (R,) rad in the map frame (NaN until the first odometry),
    velocity (R, 2) m/s measured in the world frame, active (R,) fresh odometry,
    owned (R,) commanded by this controller, last_command (R, 2) world velocity issued
    last tick after the safety layer (measured velocity for robots not owned), period h (s),
    time (s, node clock), pose_age (R,) s since each robot's odometry was stamped (None or
    NaN: unknown).
    """

    robots: list[str]
    owned: np.ndarray
    positions: np.ndarray
    yaw: np.ndarray
    velocity: np.ndarray
    active: np.ndarray
    last_command: np.ndarray
    period: float
    time: float
    pose_age: np.ndarray | None = None


def odometry_age(now: float, stamps, arrivals, timeout: float) -> np.ndarray:
    """Each robot's odometry age (s) at ``now``: from its ``stamps`` where it has one (a
    zero stamp is none), at most ``timeout`` beyond its ``arrivals`` (a robot whose clock is
    off does not look older than that), else from its arrival; NaN before the first."""
    stamps = np.asarray(stamps, dtype=float)
    arrived = np.maximum(now - np.asarray(arrivals, dtype=float), 0.0)
    stamped = np.isfinite(stamps) & (stamps > 0)
    by_stamp = np.clip(now - np.where(stamped, stamps, now), 0.0, arrived + timeout)
    return np.where(stamped, by_stamp, arrived)
