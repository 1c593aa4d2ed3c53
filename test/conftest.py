"""Every ROS participant a test starts stays on loopback, on a domain no parallel run uses."""
import os

from mantis_rig.ros_env import claim_free_domain

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# scripts/ros_env.sh derives a domain from its PID; a lock-claimed one is safe against
# any parallel pytest run on this machine, so it replaces it.
os.environ['ROS_DOMAIN_ID'] = str(claim_free_domain())
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
