"""mantis_sim: physics of the mantis-shrimp four-bar (no ROS imports)."""
