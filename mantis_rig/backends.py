"""Build a device for a backend name: 'hardware' (KDC101, NI-DAQmx) or 'sim' (the simulated world).

The simulated devices need a WorldPort (`port`: a LocalWorldPort, in the simulated rig's process)
and, for the sensors, the scene (a mantis_sim Scene or a scene name). The
hardware drivers are imported only when asked for, so the simulated rig runs without pyserial
or nidaqmx; the simulated ones (scipy: ~2 s) at import, so that a node pays for them when it
starts rather than inside its configure transition. Devices come back unopened.

The backends' names (BACKENDS) and their check (`check_backend`) live in mantis_rig.contract,
the layer below, which imports nothing of this module.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Optional

from mantis_rig.contract import (  # the backends' check and the parameters' defaults
    DEFAULT_SERIAL_PORT,
    DEFAULT_TRIGGER_OUTPUT,
    check_backend,
)
from mantis_rig.hardware.device_interfaces import (
    CameraTrigger,
    ConfigurationError,
    DaqConfig,
    ForceDaq,
    Stage,
    StageLimits,
)
from mantis_rig.simulated.sim_camera import SimCameraTrigger
from mantis_rig.simulated.sim_force import SimForceDaq
from mantis_rig.simulated.sim_stage import SimStage
from mantis_rig.simulated.world_port import WorldPort
from mantis_rig.trial.stage_guard import StageGuard
from mantis_sim.scene import Scene, load_scene

if TYPE_CHECKING:
    from mantis_rig.hardware.discovery import StageChoice


def make_stage(backend: str, port: Optional[WorldPort] = None, *,
               serial_port: str = DEFAULT_SERIAL_PORT, stage_serial_number: str = '',
               choice: Optional[StageChoice] = None, counts_per_mm: Optional[float] = None,
               limits: Optional[StageLimits] = None, force_ceiling_n: Optional[float] = None,
               max_force_age_s: Optional[float] = 0.5,
               clock_s: Optional[Callable[[], float]] = None) -> Stage:
    """On hardware, `stage_serial_number` (a KDC101's serial number, or 'auto' for the only
    KDC101 on the machine) finds the port instead of `serial_port`
    (discovery.choose_kdc101: DiscoveryError, naming what was found, unless exactly one
    controller matches); the stage's `choice` attribute says which port and why. A `choice`
    already made (discovery.choose_kdc101: `mantis doctor` reports it before it builds the
    stage) is taken as it is, in place of both.
    With `force_ceiling_n`, the stage comes wrapped in a StageGuard: the caller must then
    feed it every force reading (StageGuard.observe_force), or pulls are refused and stopped
    once the readings are older than `max_force_age_s` on `clock_s` (default: monotonic wall
    time; the simulated rig passes its simulated clock)."""
    if check_backend(backend) == 'sim':
        stage: Stage = SimStage(_world(port, 'stage'), limits)
    else:
        from mantis_rig.hardware.discovery import choose_kdc101
        from mantis_rig.hardware.kdc101 import Z8_COUNTS_PER_MM, Kdc101Stage
        if choice is None:
            choice = choose_kdc101(serial_port, stage_serial_number)
        stage = Kdc101Stage(choice.port, counts_per_mm or Z8_COUNTS_PER_MM, limits=limits)
        stage.choice = choice
    if force_ceiling_n is None:
        return stage
    clock = {'clock_s': clock_s} if clock_s is not None else {}
    return StageGuard(stage, force_ceiling_n, max_force_age_s=max_force_age_s, **clock)


def make_force_daq(backend: str, port: Optional[WorldPort] = None, *, scene=None,
                   overrides=(), seed: int = 0,
                   config: Optional[DaqConfig] = None) -> ForceDaq:
    if check_backend(backend) == 'sim':
        return SimForceDaq(_world(port, 'load cell'), _scene(scene, overrides), seed, config)
    from mantis_rig.hardware.nidaq_force import NidaqForceDaq
    return NidaqForceDaq(config)


def make_camera_trigger(backend: str, port: Optional[WorldPort] = None, *, scene=None,
                        overrides=(), output: str = DEFAULT_TRIGGER_OUTPUT) -> CameraTrigger:
    if check_backend(backend) == 'sim':
        return SimCameraTrigger(_world(port, 'camera'), _scene(scene, overrides))
    from mantis_rig.hardware.nidaq_trigger import NidaqCameraTrigger
    return NidaqCameraTrigger(output)


def _world(port: Optional[WorldPort], device: str) -> WorldPort:
    if port is None:
        raise ConfigurationError(f'the simulated {device} needs a WorldPort to the simulated '
                                 f'world (a LocalWorldPort)')
    return port


def _scene(scene, overrides):
    if isinstance(scene, Scene):
        return scene.with_overrides(list(overrides)) if overrides else scene
    if not scene:
        raise ConfigurationError('the simulated sensors need a scene (name or Scene)')
    return load_scene(scene, list(overrides))
