"""Olfati-Saber (2006) / La and Sheng (2009) flocking with target tracking: law, scenarios,
metrics."""
