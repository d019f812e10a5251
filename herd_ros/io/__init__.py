"""File formats: GPS CSV / Movebank / GPX readers and rosbag2 reading and writing."""
