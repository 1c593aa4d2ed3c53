"""The hardware layout of the stack on fakes, for the fault-injection suite (issue 41): the KDC101
emulator (test/fakes/kdc101_emulator.py) on a pseudo-terminal in this process, and the nidaqmx
fake (test/fakes_nidaq) in the load cell's and camera's node processes, whose load cell reads a
tendon that follows the emulated stage: slack up to TAUT_MM past the start, then a spring of
K_N_PER_MM, released (0 N for good) RELEASE_MM of pull later.

`HardwareRig(work)` starts the emulator and a thread that writes its position to a file every
5 ms; `env()` is the environment a `mantis bringup --backend hardware` needs for its node
processes to find the fake (test/hardware_shim first on PYTHONPATH, the file named in
MANTIS_FAKE_STAGE_FILE); `command(args)` runs `mantis` with stage_node's serial_port set to the
emulator's port (the command line has no option for it: test/hardware_shim/mantis_on_port.py).
"""
from __future__ import annotations

import os
from pathlib import Path
import struct
import sys
import threading
import time

from fakes.kdc101_emulator import Kdc101Emulator

TEST = Path(__file__).resolve().parent
SHIM = TEST / 'hardware_shim'
START_MM = 5.0           # the trials' start (--set start_position_mm)
TAUT_MM = 0.3            # slack taken up this far past the start
K_N_PER_MM = 1.0
RELEASE_MM = 2.5         # the robot releases this far into the pull


class HardwareRig:
    def __init__(self, work: Path):
        self.emulator = Kdc101Emulator(position_mm=START_MM, homed=False).start()
        self.file = work / 'stage_position'
        self.file.write_bytes(struct.pack('<d', START_MM))
        self.samples: list[tuple[float, float, float]] = []    # (wall, position m, velocity)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._follow, daemon=True,
                                        name='kdc101-position-feed')
        self._thread.start()

    def _follow(self) -> None:
        while not self._stop.wait(0.005):
            emu = self.emulator
            now, position, moving = time.monotonic(), emu.position_mm, emu.moving
            tmp = self.file.with_suffix('.tmp')
            tmp.write_bytes(struct.pack('<d', position))
            os.replace(tmp, self.file)
            self.samples.append((now, position * 1e-3, emu.speed_mm_s * 1e-3 if moving else 0.0))

    def env(self) -> dict:
        paths = [str(SHIM), str(TEST), os.environ.get('PYTHONPATH', '')]
        return {**os.environ, 'PYTHONPATH': os.pathsep.join(p for p in paths if p),
                'MANTIS_FAKE_STAGE_FILE': str(self.file)}

    def command(self, args) -> list:
        return [sys.executable, str(SHIM / 'mantis_on_port.py'), self.emulator.port, *args]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.emulator.close()
