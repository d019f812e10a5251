"""Identification: batch least squares, recursive least squares, residual whiteness."""
