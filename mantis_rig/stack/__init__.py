"""The rig's node stack as a whole: the node table both layouts build from (`node_table`),
bringing it up in one process or one per node (`bringup`), watching its processes
(`watchdog`), and a command's ROS session (`command_session`). Above the nodes."""
