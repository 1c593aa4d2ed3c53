"""Simulated load-cell DAQ: samples the simulated world's tendon tension.

Sample i after start() is taken at t0 + i / rate on the world's clock, t0 being the first
sample instant at or after start(). The load cell and amplifier (effect loadcell_dynamics)
shape the signal (mantis_sim.sensors); the reading in volts is scaled as on the rig:
force = (volts - offset_v) * newtons_per_volt. Like the DAQ's buffer, the backend holds
BUFFER_S of samples: a reader that falls further behind loses the oldest (overrun flagged).
"""
from __future__ import annotations

from dataclasses import replace
import math
from typing import Optional

import numpy as np

from mantis_rig.hardware.device_interfaces import DaqConfig, DeviceError, ForceBlock, ForceDaq
from mantis_rig.hardware.nidaq_force import validate_config
from mantis_rig.simulated.world_port import WorldPort
from mantis_sim.scene import Scene
from mantis_sim.sensors import LoadCellSensor

BUFFER_S = 1.0


class SimForceDaq(ForceDaq):
    max_sample_rate_hz = 2_000_000.0     # as the USB-6363 it stands in for

    def __init__(self, port: WorldPort, scene: Scene, seed: int = 0,
                 config: Optional[DaqConfig] = None):
        self.port = port
        self.scene = scene
        self.seed = seed
        self.config = config or DaqConfig()
        validate_config(self.config)
        self._open = False
        self._running = False
        self._t0_s = 0.0
        self._next_index = 0
        self._sensor: LoadCellSensor | None = None

    @property
    def period_s(self) -> float:
        return 1.0 / self.config.sample_rate_hz

    def open(self) -> None:
        self.port.now_s()
        self._open = True

    def close(self) -> None:
        self._running = False
        self._open = False

    def configure(self, config: DaqConfig) -> None:
        validate_config(config)
        if self._running:
            raise DeviceError('cannot configure the simulated DAQ while it is acquiring')
        self.config = config

    def start(self) -> None:
        self._require_open('start')
        now = self.port.now_s()
        self._t0_s = math.ceil(now / self.period_s) * self.period_s
        self._next_index = 0
        self._sensor = LoadCellSensor(self.scene, self.config.sample_rate_hz, self.seed)
        self._running = True

    def stop(self) -> None:
        self._running = False

    def read_block(self, timeout_s: float = 1.0) -> ForceBlock:
        if not self._running:
            raise DeviceError('read_block: the simulated DAQ is not acquiring (call start())')
        n, period = self.config.block_size, self.period_s
        overrun = False
        oldest = math.ceil((self.port.now_s() - BUFFER_S - self._t0_s) / period)
        if oldest > self._next_index:
            self._next_index, overrun = oldest, True
        first = self._next_index
        t_first = self._t0_s + first * period
        volts = self._sensor.measure_volts(self.port.tendon_force(t_first, period, n, timeout_s))
        self._next_index += n
        force = (volts - self.config.offset_v) * self.config.newtons_per_volt
        return ForceBlock(t0_s=t_first, period_s=period, force_n=force, first_index=first,
                          overrun=overrun)

    def tare(self, duration_s: float = 0.2) -> float:
        """Average the input over the next duration_s and make that zero force."""
        self._require_open('tare')
        period = self.period_s
        n = max(1, round(duration_s / period))
        start = math.ceil(self.port.now_s() / period) * period
        sensor = LoadCellSensor(self.scene, self.config.sample_rate_hz, self.seed + 1)
        volts = sensor.measure_volts(self.port.tendon_force(start, period, n, duration_s + 10.0))
        offset = float(np.mean(volts))
        self.config = replace(self.config, offset_v=offset)
        return offset

    def _require_open(self, what: str) -> None:
        if not self._open:
            raise DeviceError(f'cannot {what}: the simulated DAQ is not open')
