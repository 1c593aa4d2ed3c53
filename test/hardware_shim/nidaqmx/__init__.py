"""The nidaqmx fake (test/fakes_nidaq) in place of nidaqmx, for a node process of the hardware
layout on fakes (test/hardware_rig.py): importing it installs the fake's modules. Its load cell
reads a tendon that follows the emulated stage (the position in MANTIS_FAKE_STAGE_FILE), and
delivers samples no faster than the wall clock, as the USB-6363 does."""
import os
import struct
import sys
import time

from fakes_nidaq import FakeDaqSystem
import hardware_rig
import numpy as np

VOLTS_AT_REST = 0.0               # an unloaded load cell (the amplifier zeroed)
NEWTONS_PER_VOLT = 11.12          # loadcell_node's default scale
SLACK_N = 0.4                     # the tendon just taut (slack_force_n: 0.3 N)


class TendonDaq(FakeDaqSystem):
    started = None
    released = False
    latched = False           # the robot seen latched: the stage at or before the taut point

    def volts(self, task, samples):
        rate = task.timing.samp_clk_rate
        if self.started is None:
            self.started = time.monotonic() - self.position / rate
        delay = self.started + (self.position + samples) / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        return super().volts(task, samples)


def stage_mm() -> float:
    try:
        with open(os.environ['MANTIS_FAKE_STAGE_FILE'], 'rb') as f:
            return struct.unpack('<d', f.read(8))[0]
    except (OSError, KeyError, struct.error):
        return hardware_rig.START_MM


def tendon_v(index):
    """Slack below the start + TAUT_MM; then SLACK_N plus a spring; 0 N once released by a pull
    through RELEASE_MM, until the stage is back in the slack, where the person re-latches the
    robot (as the simulated world's operator does). A load cell started with the stage beyond
    the release point (a bring-up after a fault stopped the stage there) reads a latched robot
    once the stage has returned into the slack, not a release it never saw."""
    stretch = stage_mm() - (hardware_rig.START_MM + hardware_rig.TAUT_MM)
    if stretch < 0:
        system.latched, system.released = True, False
    elif stretch > hardware_rig.RELEASE_MM and system.latched:
        system.released = True
    force = 0.0 if system.released or not system.latched or stretch < 0 else \
        SLACK_N + hardware_rig.K_N_PER_MM * stretch
    return np.full(np.shape(index), VOLTS_AT_REST + force / NEWTONS_PER_VOLT)


system = TendonDaq(signal_v=tendon_v)
sys.modules.update(system.modules())
