"""Herding: Strömbom's sheep and shepherd, the benchmark, the model herder, the live graph."""
