"""How much of each animal the live law has seen: the model steps at which it was in the herd.

The estimator learns each animal's law from the snapshots where the animal is present, so
an animal whose collar starts late (or came back after days) has a law of a few steps while
the herd's has hundreds. A robot that follows such a law follows its prior and a handful of
points: on a 72-hour duty-cycled cattle analog, a robot whose animal's collar started 10 h
late ran 190 m from its animal at full speed 16 minutes after the collar's first fix. The
controller's warm-up (``model_min_updates``: the model's updates before any robot moves,
three model steps per parameter in the demo's setup) therefore holds per animal too: a
robot waits until its animal has been in the herd for that many model steps,

    n_i = #{ ⌊t/Δt⌋ : animal i has a pose on /herd/poses at tick t }

(the distinct model steps with its pose; a herd clock finer than Δt counts each step once).

Plain numpy; no ROS.
"""
from __future__ import annotations

import numpy as np


class AnimalSteps:
    """n_i of every animal from the herd ticks (module docstring)."""

    def __init__(self, n_animals: int, dt: float):
        self.dt = float(dt)
        self.count = np.zeros(int(n_animals), dtype=np.int64)
        self._last = np.full(int(n_animals), np.nan)

    def observe(self, t: float, positions: np.ndarray) -> None:
        """A herd tick at ``t`` (s) with the animals' positions (N, 2) (NaN = no pose)."""
        present = np.isfinite(np.asarray(positions, dtype=float)).all(axis=-1)
        step = np.floor(float(t) / self.dt)
        new = present & (self._last != step)
        self.count[new] += 1
        self._last[new] = step

    def ready(self, min_steps: int) -> np.ndarray:
        """(N,) whether each animal has been in the herd for at least ``min_steps`` steps."""
        return self.count >= int(min_steps)
