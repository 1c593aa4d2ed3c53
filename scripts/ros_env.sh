# Sourced by the scripts: keep DDS on this machine, on a domain of this run's own.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
if [ -z "${ROS_DOMAIN_ID:-}" ]; then
  # 1..101 keeps clear of Fast DDS port clashes; derived from the PID so parallel runs differ.
  export ROS_DOMAIN_ID=$(( ($$ % 101) + 1 ))
fi
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
