"""The herding graph's parameters: herd_sim → fleet_sim → controller (mode ``herding``),
one function for ``launch/herding.launch.py`` and ``herd-ros demo --herding`` so the two
cannot drift.

The setting is the benchmark's (:mod:`herd_ros.herding.benchmark`): a 150 m field, the goal
circle of radius 15 m at (20, 20), Strömbom's sheep starting in a 40 m square about
(100, 100), herders at 1.5 × the animals' speed starting in the field's far corner (145,
145), beyond the herd as seen from the goal. The
graph runs in simulated time (herd_sim drives ``/clock``, ``rate`` × real time).

Plain Python; no ROS.
"""
from __future__ import annotations

from herd_ros.herding.benchmark import GOAL, GOAL_RADIUS, START_BOX

#: where the herd starts (centre of its square) and the herders (the first one; the
#: others 3 m apart along −y)
HERD_START = (100.0, 100.0)
HERDERS_START = (145.0, 145.0)
#: animal speed (m/s) and the herders' (1.5 ×, Strömbom's setting)
ANIMAL_SPEED = 1.0
HERDER_SPEED = 1.5


def robot_names(n: int) -> list[str]:
    """The herders, in /fleet/poses order."""
    return [f'herder_{k + 1}' for k in range(n)]


def budget_s(n_animals: int) -> float:
    """Simulated seconds a run may take: the benchmark's step budget at 1 s per step."""
    return 1500.0 + 30.0 * n_animals


def herding_parameters(n_animals: int = 14, herders: int = 1, rate: float = 10.0,
                       seed: int = 0, n_neighbours: int = 0, noise: float = 0.3,
                       herder: str = 'strombom', model_warmup: str = 'strombom') -> dict:
    """{node: {'ros__parameters': {...}}} for herd_sim, fleet_sim and controller (each
    node also reads its ``config/<node>.yaml``; these override it); ``herder``: the
    controller's policy, ``strombom`` or ``model``; ``model_warmup``: what the robots do
    while the model herder learns, ``strombom`` or ``hold``."""
    if n_animals < 2 or herders < 1 or not rate > 0:
        raise ValueError('n_animals >= 2, herders >= 1 and rate > 0 needed')
    if herder not in ('strombom', 'model'):
        raise ValueError(f'herder must be strombom or model, got {herder!r}')
    robots = robot_names(herders)
    poses = []
    for k in range(herders):
        poses += [HERDERS_START[0], HERDERS_START[1] - 3.0 * k, -2.356]     # facing the herd
    return {
        'herd_sim': {'ros__parameters': {
            'n_animals': int(n_animals), 'start_center': list(HERD_START),
            'start_box': START_BOX, 'seed': int(seed), 'n_neighbours': int(n_neighbours),
            'noise': float(noise), 'speed': ANIMAL_SPEED, 'publish_clock': True,
            'rate': float(rate), 'clock_step_s': 0.05}},
        'fleet_sim': {'ros__parameters': {
            'use_sim_time': True, 'robots': robots, 'initial_poses': poses,
            'rate_hz': 10.0, 'max_speed': HERDER_SPEED, 'max_accel': 3.0,
            'cmd_timeout_s': 1.0}},
        'controller': {'ros__parameters': {
            'use_sim_time': True, 'robots': robots, 'mode': 'herding', 'rate_hz': 5.0,
            'max_speed': HERDER_SPEED, 'herder_speed': HERDER_SPEED, 'goal': list(GOAL),
            'goal_radius': GOAL_RADIUS, 'herding_seed': int(seed), 'odom_timeout_s': 2.0,
            'herder': herder, 'model_warmup': model_warmup}},
    }
