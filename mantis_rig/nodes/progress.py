"""How far a consumer of the rig's streams has got, for the simulated world to wait for.

A consumer whose reactions must come in time on the rig's clock (the supervisor's trial thread,
the stage's force guard) publishes ``progress`` (contract.PROGRESS, std_msgs/Header): frame_id
names it, stamp is the rig time up to which it has heard the force stream and acted on it; a
stamp of 0 says it waits for nothing now. On a busy machine the simulated world then slows
down instead of running ahead of a starved consumer (mantis_rig.simulated.sim_world_node); on
hardware nothing listens, and the messages cost a publish each. A consumer in the world's own
process (sim_rig's stage guard; the supervisor of a one-process stack) reports by a direct call
to the world instead (``ProgressReporter.report_to``).
"""
from __future__ import annotations

from std_msgs.msg import Header

from mantis_rig import contract

from .device_node import time_msg

# Progress is sent once it has moved on by this much rig time (or back, or to 0): a world step
# (the world may run `max_lead_s`, 0.05 s, ahead of it).
PROGRESS_STEP_S = 0.01


class ProgressReporter:
    """Publishes one consumer's progress on ``node``; safe from any thread."""

    def __init__(self, node, part: str):
        self._frame_id = f'{node.get_name()}/{part}'
        self._publisher = node.create_publisher(Header, contract.PROGRESS.name,
                                                contract.PROGRESS.qos.publisher())
        self._sent_s: float | None = None
        self._direct = None

    def report_to(self, direct) -> None:
        """Report by calling ``direct(frame_id, rig_time_s)`` instead of publishing: the
        simulated world is in this process (sim_world_node.note_progress)."""
        self._direct = direct

    def report(self, rig_time_s: float) -> None:
        last = self._sent_s
        if rig_time_s > 0.0 and last and last <= rig_time_s < last + PROGRESS_STEP_S:
            return
        self._sent_s = rig_time_s
        direct = self._direct
        if direct is not None:
            direct(self._frame_id, rig_time_s)
            return
        try:
            self._publisher.publish(Header(stamp=time_msg(rig_time_s), frame_id=self._frame_id))
        except RuntimeError:     # shutting down (its context gone): nothing waits for it then
            pass
