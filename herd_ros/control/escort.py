"""A robot that waits for its animal's law escorts its animal (issue 30: robots start where
their animals are).

With a live model a robot waits before it follows its animal's law: until the estimator's
first ``model_min_updates`` updates are in, and until its own animal has been in the herd
for as many model steps (a collar that starts late has a young law;
:mod:`herd_ros.control.animal_steps`). On duty-cycled collars that is hours: on 12 h of
cattle-like fixes at a 2-minute model step the robots held still for the first two hours at
their animals' first poses, a formation of different moments (a collar that starts an hour
late puts its robot at a place its herd had left), while the herd walked 150 m on. The law
then started from there.

Waiting, a robot now goes to its animal instead: a first-order approach to the animal's
latest pose on ``/herd/poses``, with the animal's velocity fed forward,

    v_k = u_k + (a_k − p_k) / τ                                             (E1)

(u_k the animal's velocity over the last herd tick, 0 where unknown; τ the herd clock's
step: the gap shrinks by e^{−h/τ} over a time h, the safety layer caps the speed).

**A slow loop.** (E1) is feedback on the robot's position, and the position it sees is
as old as its odometry, and a command holds until the next tick. With a lag L (the age of
the odometry plus the time since the previous tick) the loop ``ṗ(t) = (a − p(t − L))/τ``
oscillates once L/τ nears π/2 and swings ever wider beyond it (the delayed first-order
loop; Åström & Murray, *Feedback Systems*, 2008, §10.4). So τ is never below the lag:

    τ_k = max(τ, L_k)                                                      (E2)

On a herd replayed at 1 400 × real time the controller ran every 40-70 s of data (not its
7.5 s) on odometry 50-140 s old; at τ = 30 s its robots swung 100-200 m about animals
that stood, and started their laws 117-137 m from them. With (E2), on the first 3 h of
that herd at 1 400 × (4 runs, 3 robots): the gap while escorting 22 m at the median
against 97 m, p90 87 against 172 m, the robots 4-30 m from their animals when their laws
took over against 19-183 m. (τ at e·L, the bound for no overshoot at all, trailed the
walking animals more: 26 m, p90 141 m.) At the rates a robot runs in the field L is
below τ and (E2) changes nothing. Without u_k a
robot trails an animal walking at speed v by v τ (the lag of a first-order tracker of a
ramp); with it, by nothing once the gap has closed. So when its law takes over the robot
starts where its animal is at that moment. A robot whose animal has no pose, or which has
no odometry, holds still (v = 0). What a robot
does while it escorts is not the law's: the pace and place matches leave those samples out
and the demo scores each robot from the tick its law took over.

Plain numpy; no ROS (the controller's mode ``herd_model`` calls it, parameter
``wait_mode``).
"""
from __future__ import annotations

import numpy as np


def loop_lag(pose_age, since_last_tick) -> np.ndarray:
    """L of (E2) per robot (R,): the age of its odometry (s; NaN or None: 0) plus the time
    since the controller's previous tick (s; NaN or None: 0), never negative."""
    age = np.nan_to_num(np.asarray(0.0 if pose_age is None else pose_age, dtype=float),
                        nan=0.0)
    gap = 0.0 if since_last_tick is None or not np.isfinite(since_last_tick) \
        else float(since_last_tick)
    return np.maximum(age, 0.0) + max(gap, 0.0)


def escort_velocity(robot_xy, animal_xy, tau: float, animal_velocity=None,
                    ahead: float = 0.0, lag=None) -> np.ndarray:
    """(E1): each robot's velocity (R, 2) towards its animal's pose, ``robot_xy`` and
    ``animal_xy`` (R, 2) (NaN where unknown: that robot holds still), time constant ``tau``
    (s, > 0; a number or one per robot), raised to each robot's loop ``lag`` (R,) where
    given ((E2), :func:`loop_lag`), the animals' velocities ``animal_velocity`` (R, 2) fed
    forward (None or NaN: none); the pose is carried on with it by ``ahead`` seconds (the
    time since the herd tick that gave the pose, at most ``tau``)."""
    tau = np.asarray(tau, dtype=float)
    if not np.all(tau > 0):
        raise ValueError(f'tau must be positive, got {tau}')
    p = np.asarray(robot_xy, dtype=float).reshape(-1, 2)
    a = np.asarray(animal_xy, dtype=float).reshape(-1, 2)
    if lag is not None:
        tau = np.maximum(tau, lag)                                     # (E2)
    tau = np.broadcast_to(tau, (len(p),))[:, None]
    u = np.zeros_like(p) if animal_velocity is None else \
        np.asarray(animal_velocity, dtype=float).reshape(-1, 2)
    u = np.where(np.isfinite(u).all(axis=-1, keepdims=True), u, 0.0)
    v = (a + u * np.clip(ahead, 0.0, tau) - p) / tau + u
    return np.where(np.isfinite(v).all(axis=-1, keepdims=True), v, 0.0)
