"""Swarm imitation (Rahman, White et al., ACC 2023): policies, Boids simulator, learning,
metrics."""
