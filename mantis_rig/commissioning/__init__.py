"""Commissioning: the checks `mantis doctor` runs on the rig's devices before a trial (the ROS
environment and disk, the NI DAQ, load cell, camera trigger and stage, and with --move a guarded
jog), the rig parameters file they read, and the report they make. Devices only: no node.
"""
