"""mantis_rig: ROS 2 software for the mantis-shrimp robot rig and its simulated twin."""
