"""The simulated high-speed camera and what it shares with the tracking of real video: the
camera calibration (:mod:`.calibration`), the tracker's CSV form (:mod:`.tracker_csv`) and the
renderer that films a strike (:mod:`.render`). No ROS, nothing of the rig's package."""
