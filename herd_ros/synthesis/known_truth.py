"""Herds with known truth: a random model in the class of Schwager et al. (2007), and data from it.

The truth has damping a_i ~ U(0.90, 0.97), pairwise θ1_ij ~ U(0.002, 0.006) with
equilibrium distances θ2_ij/θ1_ij ~ U(10, 50) m, process noise only (w_i ~ N(0, s² I)),
and a circulating, non-gradient environment field on an even RBF grid (σ = 2/3 spacing):
a vortex about the centre of the bounds plus an inward pull that grows with the distance
from the centre, so the herd circulates and stays in the region. The field coefficients are
the desired vector field at each centre scaled by the basis' partition-of-unity factor
(Σ_k φ_k ≈ σ√(2π)/s² on an even grid of spacing s), so the truth lies in the model class
on exactly the grid a fit is given with ``--grid``/``--bounds``.
"""
from __future__ import annotations

import numpy as np

from herd_ros.model.herd_model import AgentLaw, HerdModel
from herd_ros.model.rbf_field import FieldGrid, RbfBasis


def circulating_field(points: np.ndarray, center, half_width: float, swirl: float = 0.03,
                      pull: float = 0.03) -> np.ndarray:
    """A vortex plus a radial pull: g(p) = swirl·J r̂·ρ − pull·r̂·ρ², ρ = |p − c|/half_width."""
    d = np.asarray(points, dtype=float) - np.asarray(center, dtype=float)
    rho = np.sqrt((d ** 2).sum(-1, keepdims=True)) / half_width
    rot = np.stack([-d[..., 1], d[..., 0]], axis=-1) / half_width
    return swirl * rot * np.exp(-rho ** 2) * 2.0 - pull * (d / half_width) * rho


def make_truth_model(n_agents: int, seed=0, grid: tuple[int, int] = (6, 6),
                     bounds=(-150.0, 150.0, -150.0, 150.0), dt: float = 1.0,
                     noise_std: float = 0.05, damping_range=(0.90, 0.97),
                     equilibrium_range=(10.0, 50.0), theta1_range=(0.002, 0.006),
                     swirl: float = 0.03, pull: float = 0.03, agents=None) -> HerdModel:
    """A random herd model with known parameters (see the module docstring)."""
    rng = np.random.default_rng(seed)
    agents = agents or [f'agent_{k + 1}' for k in range(n_agents)]
    fg = FieldGrid(grid[0], grid[1], tuple(float(b) for b in bounds))
    centers = fg.centers()
    basis = RbfBasis(centers, np.full(len(centers), fg.sigma))
    xmin, xmax, ymin, ymax = fg.bounds
    center = ((xmin + xmax) / 2, (ymin + ymax) / 2)
    half = min(xmax - xmin, ymax - ymin) / 2
    spacing = float(np.mean(fg.spacing))
    unity = fg.sigma * np.sqrt(2 * np.pi) / spacing ** 2
    laws = {}
    for i, a in enumerate(agents):
        neighbors = [b for b in agents if b != a]
        theta1 = rng.uniform(*theta1_range, size=len(neighbors))
        theta2 = theta1 * rng.uniform(*equilibrium_range, size=len(neighbors))
        g = circulating_field(centers, center, half, swirl, pull)
        gain = rng.uniform(0.8, 1.2)
        laws[a] = AgentLaw(damping=float(rng.uniform(*damping_range)), neighbors=neighbors,
                           theta1=theta1, theta2=theta2, basis=basis,
                           field_u=gain * g[:, 0] / unity, field_v=gain * g[:, 1] / unity,
                           noise_cov=np.eye(2) * noise_std ** 2)
    return HerdModel(agents=agents, dt=dt, laws=laws)


def initial_positions(model: HerdModel, seed=0, spread: float = 30.0,
                      min_separation: float = 5.0) -> np.ndarray:
    """Random p^0 (N, 2) about the centre of the first agent's grid, agents ≥ min_separation
    apart."""
    rng = np.random.default_rng(seed)
    c = model.laws[model.agents[0]].basis.centers.mean(axis=0)
    n = model.n_agents
    for _ in range(1000):
        p = c + rng.uniform(-spread, spread, size=(n, 2))
        d = np.sqrt(((p[:, None] - p[None]) ** 2).sum(-1)) + np.eye(n) * 1e9
        if d.min() >= min_separation:
            return p
    return c + spread * np.column_stack([np.cos(np.arange(n)), np.sin(np.arange(n))])


def _profile_coefficients(profile, force) -> np.ndarray:
    """Least-squares coefficients c of Σ_b c_b ψ_b(d) ≈ ``force(d)`` on (0, r)."""
    d = np.linspace(0.3, profile.radius * 0.999, 400)
    c, *_ = np.linalg.lstsq(profile.features(d), force(d), rcond=None)
    return c


def make_driven_truth(n_sheep: int = 15, seed=0, dt: float = 1.0, noise_std: float = 0.1):
    """A flock driven by a dog, in the shared law with the dog's own profile (the sheep-and-
    dog case of :mod:`herd_ros.model.shared_law`), and its initial positions.

    Sheep: damping U(0.85, 0.95), cohesion F(d) = 0.03 (d − 5)/5 · e^(−d/15) (repelled
    below 5 m) pooled over the other sheep within 40 m, and flight from the dog
    H(d) = −0.25 e^(−d/15) within 60 m (each sheep's gains × U(0.8, 1.2)). The dog: damping
    0.9, drawn to the sheep beyond 15 m and repelled closer (F(d) = 0.02 (d − 15)/15), so it
    hovers at the flock's edge and keeps pushing it; it moves erratically (process noise
    3 noise_std against the sheep's noise_std, N(0, s² I)).
    Returns (model, p0 (N, 2)): the sheep within ±4 m of the origin, the dog 25 m east."""
    from herd_ros.model.shared_law import DistanceProfile, SharedLawModel
    rng = np.random.default_rng(seed)
    agents = [f'sheep_{k + 1}' for k in range(n_sheep)] + ['dog']
    n = len(agents)
    pooled = DistanceProfile.even(40.0, 6)
    own = DistanceProfile.even(60.0, 6)
    c_sheep = _profile_coefficients(pooled, lambda d: 0.03 * (d - 5.0) / 5.0 * np.exp(-d / 15))
    c_dog = _profile_coefficients(pooled, lambda d: 0.02 * (d - 15.0) / 15.0)
    h_sheep = _profile_coefficients(own, lambda d: -0.25 * np.exp(-d / 15.0))
    gains = rng.uniform(0.8, 1.2, size=(n_sheep, 2))
    coef = np.vstack([np.outer(gains[:, 0], c_sheep), c_dog])
    own_coef = np.zeros((n, 1, own.size))
    own_coef[:n_sheep, 0] = np.outer(gains[:, 1], h_sheep)
    basis = RbfBasis(np.zeros((1, 2)), np.ones(1) * 1e3)
    model = SharedLawModel(
        agents=agents, dt=dt, profile=pooled,
        damping=np.r_[rng.uniform(0.85, 0.95, n_sheep), 0.9], profile_coef=coef,
        bases=[basis] * n, field_u=[np.zeros(1)] * n, field_v=[np.zeros(1)] * n,
        noise_cov=np.eye(2) * (noise_std * np.r_[np.ones(n_sheep), 3.0])[:, None, None] ** 2,
        own_agents=['dog'], own_profile=own, own_coef=own_coef)
    p0 = np.vstack([rng.uniform(-4.0, 4.0, size=(n_sheep, 2)), [[25.0, 0.0]]])
    return model, p0


#: the alignment kernel of :func:`with_alignment`: K(d) at the bumps of a 4-bump kernel
#: over 40 m (strongest close by, fading with distance)
ALIGNMENT_WEIGHTS = (0.25, 0.15, 0.08, 0.03)


def with_alignment(model, weights=ALIGNMENT_WEIGHTS, radius: float = 40.0,
                   neighbourhood: str = 'radius', nearest: int = 7, seed=0):
    """``model`` with a known velocity alignment (:mod:`herd_ros.model.alignment`): every
    agent's kernel K_i(d) = Σ_b w_ib ψ_b(d) on ``len(weights)`` bumps over ``radius``, with
    w_ib = ``weights[b]`` × a gain U(0.8, 1.2) per agent. Returns a new model."""
    import dataclasses

    from herd_ros.model.alignment import AlignmentKernel, VelocityAlignment
    rng = np.random.default_rng(seed)
    kernel = AlignmentKernel.even(radius, len(weights), neighbourhood, nearest)
    gains = rng.uniform(0.8, 1.2, size=(model.n_agents, 1))
    return dataclasses.replace(model, alignment=VelocityAlignment(
        kernel, gains * np.asarray(weights, dtype=float)[None, :]))
