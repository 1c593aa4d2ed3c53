"""The rig's node stack as a whole, and the ROS sessions of the commands: the node table both
layouts build from (`node_table`), bringing the stack up in one process or one per node
(`bringup`), watching its processes (`watchdog`), a trial or a bring-up run on it
(`stack_runs`), a command's ROS session and its client of a running rig (`command_session`),
and a bag replayed on ROS (`replay_session`). Above the nodes."""
