"""herd_ros: learn how a herd moves from GPS collars and drive robot fleets with it."""
