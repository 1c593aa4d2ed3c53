"""Is there room on disk for a trial's bag? An estimate from the trial's conditions, checked
against the free space before the trial starts (no ROS)."""
from __future__ import annotations

from pathlib import Path
import shutil

from mantis_rig.trial.supervisor_settings import TrialConditions

FORCE_SAMPLE_RATE_HZ = 20_000.0      # the load cell's default rate (loadcell_node)
BYTES_PER_FORCE_SAMPLE = 8           # float64, before compression
MARKERS = 5
BYTES_PER_MARKER_FRAME = MARKERS * 2 * 8 + 8     # x, y per marker and the frame time
OTHER_BYTES_PER_S = 20_000           # joint states, wrenches, diagnostics, state
FIXED_S = 20.0                       # bring-up, homing, slack, return: generous
MARGIN = 2.0                         # the estimate ignores compression; keep twice it free


def estimate_bag_bytes(conditions: TrialConditions) -> int:
    """Uncompressed size of a trial's bag: the force stream and the small topics over the
    trial's length (the pull to `travel_mm` plus a fixed allowance), and the camera window."""
    duration_s = conditions.travel_mm / conditions.pull_speed_mm_s + FIXED_S
    per_s = FORCE_SAMPLE_RATE_HZ * BYTES_PER_FORCE_SAMPLE + OTHER_BYTES_PER_S
    frames = conditions.frame_rate_hz * (conditions.pre_trigger_s + conditions.post_trigger_s)
    return int(duration_s * per_s + frames * BYTES_PER_MARKER_FRAME)


def free_space_problem(directory: Path, conditions: TrialConditions,
                       disk_usage=shutil.disk_usage) -> str | None:
    """Why a trial cannot be logged under `directory` (too little free space), or None."""
    needed = MARGIN * estimate_bag_bytes(conditions)
    probe = Path(directory)
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free = disk_usage(probe).free
    if free >= needed:
        return None
    return (f'only {free / 1e6:.1f} MB free under {directory}; a trial\'s bag needs about '
            f'{needed / MARGIN / 1e6:.1f} MB (kept free: {needed / 1e6:.1f} MB)')


__all__ = ['estimate_bag_bytes', 'free_space_problem']
