"""The trial without ROS: its conditions and their ranges, the one force ceiling, the sequence
the supervisor steps through, the force monitor and the log's disk-space check. No rclpy here:
the nodes in `mantis_rig.nodes` drive this logic over ROS."""
