"""Forward simulation of learned laws, k-step prediction, herd statistics."""
