"""Figures and summary files of the reports."""
