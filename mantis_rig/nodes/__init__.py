"""ROS 2 nodes of the rig (docs/ros_interfaces.md); a module with a main() is a console script."""
