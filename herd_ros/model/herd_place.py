"""Each agent's place in the herd: the range of its offset from the others' centroid, and
the pull that keeps a law there when it runs freely.

A herd that travels (cows crossing their pasture together, a baboon troop on its daily
route) has no fixed home range to pull an agent back to; what stays is each animal's place
among the others. With the offset

    d_i = p_i − c_−i,   c_−i the mean position of the other agents present,

a cohesive herd's offsets are stationary where its positions are not. Their mean m_i and
covariance S_i are the range of agent i's place, and the pull at that range's edge

    g_i^place = −K_i (d_i − m_i)(1 − r₀/r)₊,   K_i = Δt/(2(1 − a_i)) Q_i S_i⁻¹        (P1)

is the home pull of :mod:`herd_ros.model.space_use_field` ((S2), in its edge form
:func:`~herd_ros.model.space_use_field.edge_pull`) in the herd's frame: the
Ornstein-Uhlenbeck pull whose stationary covariance is S_i for the law's noise Q_i (the
others' own noise neglected), acting only beyond the edge of the range (r the Mahalanobis
distance of d_i − m_i in S_i, r₀ = ``HOME_RANGE_RADIUS``), so inside it the learned law
alone moves the agent. Attraction to the group's centroid is how group movement models
hold a group together (Haydon et al. 2008, Proc. R. Soc. B 275:1101; Langrock et al. 2014,
Methods Ecol. Evol. 5:190); here its strength and reach come from the data's spread.

In a model it is ``meta['herd_place']`` = (m (N, 2), K (N, 2, 2), S (N, 2, 2)), and for a
law fitted offline (:func:`with_herd_place`) also the cap c_i (N,) of each pull,

    ‖g_i^place‖ ≤ c_i = c σ_i,   σ_i² the largest eigenvalue of Q_i                     (P2)

(a drift of at most a fraction of the noise per step: one step ahead the places cost at
most √(1 + c²) − 1 in RMS, run freely they still hold). A robot fleet keeps each robot's
place among the other robots (their centroid stands for the herd's; only the robots whose
animal has a pose count in it, as only the animals present counted in the offsets the
places were learned from: :meth:`~herd_ros.control.herd_follower.HerdFollower
.environment`). The places the live
estimator publishes for the robots carry no cap: its one-step predictions are its
recursive least-squares law alone, which has no range pulls, so (P2)'s reason does not
arise there.

Plain numpy; no ROS.
"""
from __future__ import annotations

import numpy as np

from herd_ros.model.space_use_field import edge_pull, range_gain


#: c of (P2): a fitted law's place pull is at most c times its noise std per step (a
#: one-step prediction at most √(1 + c²) − 1 = 2 % worse in RMS)
PLACE_CAP = 0.2


def others_centroid(positions: np.ndarray, counted: np.ndarray | None = None) -> np.ndarray:
    """c_−i, the mean position of the agents other than i that are present (finite) and,
    given ``counted`` (N,), counted, for positions (..., N, 2); NaN where no other agent
    is."""
    p = np.asarray(positions, dtype=float)
    n = p.shape[-2]
    if counted is None and n > 1 and np.isfinite(p).all():   # everyone present (a free run)
        return (p.sum(axis=-2, keepdims=True) - p) / (n - 1)
    seen = np.isfinite(p).all(axis=-1, keepdims=True)
    if counted is not None:
        seen = seen & np.asarray(counted, dtype=bool)[:, None]
    q = np.where(seen, p, 0.0)
    total = q.sum(axis=-2, keepdims=True) - q
    count = seen.sum(axis=-2, keepdims=True) - seen
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(count > 0, total / count, np.nan)


def place_offsets(positions: np.ndarray, counted: np.ndarray | None = None) -> np.ndarray:
    """d_i = p_i − c_−i for positions (..., N, 2) (NaN where p_i or every other is; the
    centroid over the ``counted`` others only, when given)."""
    p = np.asarray(positions, dtype=float)
    return p - others_centroid(p, counted)


def herd_place(positions: np.ndarray, damping, noise_cov, dt: float,
               min_samples: int = 10):
    """(m (N, 2), K (N, 2, 2), S (N, 2, 2)) of (P1) from positions (T, N, 2) on the model
    clock: the mean and covariance of each agent's offsets and the gain for its damping a_i
    (N,) and noise Q_i (N, 2, 2). K_i = 0 for an agent with fewer than ``min_samples``
    offsets, offsets that do not spread, or a_i ≥ 1."""
    d = place_offsets(positions)
    ok = np.isfinite(d).all(axis=-1)                       # (T, N)
    n = ok.sum(axis=0).astype(float)
    z = np.where(ok[..., None], d, 0.0)
    with np.errstate(invalid='ignore', divide='ignore'):
        m = z.sum(axis=0) / n[:, None]
        e = np.where(ok[..., None], d - m, 0.0)
        s = np.einsum('tni,tnj->nij', e, e) / n[:, None, None]
    return range_gain(n, np.nan_to_num(m), np.nan_to_num(s), damping, noise_cov, dt,
                      min_samples, coupling=place_coupling(d.shape[1]))


def place_coupling(n_agents: int) -> float:
    """κ = N/(N − 1): an offset from the others' centroid moves κ times as far as its
    animal when every animal is pulled to its place (the gain and the noise of the offset
    are κ times each animal's; :mod:`herd_ros.model.discrete_gain`)."""
    return n_agents / (n_agents - 1.0) if n_agents > 1 else 1.0


def place_drift(meta: dict | None, positions: np.ndarray,
                counted: np.ndarray | None = None,
                share: np.ndarray | None = None) -> np.ndarray | float:
    """(P1) for every agent from ``meta['herd_place']``, positions (..., N, 2); 0.0
    without it (and for an agent with no other present). With a fourth entry, the cap c_i
    (N,) of a fitted law's places, each pull is shortened to at most c_i (P2). ``counted``
    (N,): the agents the others' centroid is taken over (default: every one present).
    ``share`` (N,): each agent's share of the linear pull inside its range too (a robot's,
    matched live to its animal's place spread: :mod:`herd_ros.control.place_match`)."""
    place = (meta or {}).get('herd_place')
    if place is None:
        return 0.0
    mean, gain, cov = place[:3]
    pull = edge_pull(place_offsets(positions, counted) - mean, gain, cov, share)
    if len(place) > 3:
        size = np.linalg.norm(pull, axis=-1, keepdims=True)
        pull = pull * np.minimum(1.0, np.asarray(place[3])[:, None]
                                 / np.maximum(size, 1e-300))
    return pull


def drawn_noise(model) -> np.ndarray:
    """Q_i (N, 2, 2) the law of ``model`` draws when it runs freely: its noise covariance
    times the square of its free-run noise factor (``meta['noise_scale']``, on the std;
    :mod:`herd_ros.simulation.pace_calibration`)."""
    q = np.asarray(model.noise_cov, dtype=float)
    scale = (model.meta or {}).get('noise_scale')
    if scale is None:
        return q
    return q * np.square(np.asarray(scale, dtype=float))[:, None, None]


def with_herd_place(model, positions: np.ndarray, cap: float = PLACE_CAP):
    """``model`` with each agent's place in the herd (``meta['herd_place']``, (P1) capped by
    (P2)) from ``positions`` (T, N, 2) in its agent order on its clock, the gain K_i for the
    noise the law draws (:func:`drawn_noise`); ``model`` itself when no agent gets a pull.

    The cap (P2): ‖g_i^place‖ ≤ c σ_i, σ_i² the largest eigenvalue of that noise Q_i and
    c = ``cap``. A fitted law's places come from its training data; where the herd later
    takes other places (a troop leaving its sleeping site) the linear pull of (P1) grows
    with the distance and would dominate the law one step ahead. Capped, it shifts a one-step
    prediction by at most c σ_i, against the noise σ_i it already carries: the one-step
    RMS grows by at most √(1 + c²) − 1 (2 % for c = 0.2, the one-step tolerance of
    :mod:`herd_ros.estimation.field_choice`), while run freely the capped pull, acting step
    after step, still holds the herd's shape."""
    import dataclasses
    q = drawn_noise(model)
    mean, gain, cov = herd_place(positions, model.damping, q, model.dt)
    if not np.asarray(gain).any():
        return model
    limit = float(cap) * np.sqrt(np.maximum(np.linalg.eigvalsh(q)[:, -1], 0.0))
    return dataclasses.replace(model, meta={**(model.meta or {}),
                                            'herd_place': (mean, gain, cov, limit)})


def subset_place(meta: dict | None, index) -> dict:
    """``meta``'s herd place for the agents ``index`` (a robot fleet's animals), as a dict
    to merge into the subset model's meta (empty without it)."""
    place = (meta or {}).get('herd_place')
    if place is None:
        return {}
    idx = np.asarray(index)
    return {'herd_place': tuple(np.asarray(x)[idx] for x in place)}
