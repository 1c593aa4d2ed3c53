"""The rig parameters `mantis doctor` checks against, from a ROS 2 parameters file.

The file is the stack's own (`--params-file`): a section per node, `<node>: {ros__parameters:
{...}}`, and `/**` for every node. The doctor reads stage_node's `serial_port`,
`stage_serial_number` and `counts_per_mm`; loadcell_node's `channel`, `sample_rate_hz`,
`newtons_per_volt` and `block_size`; camera_node's `lines`; the force ceiling and `out` (the
supervisor's, else a node's); the sim backend's `scene`, `set` and `seed`; and a section of its
own, `doctor:` (plain keys, no ros__parameters), with what the load cell's calibration expects
at rest: `expected_noise_n` (N rms) and `expected_offset_n` (|N|). Other keys are left to the
nodes that own them.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from pathlib import Path
from typing import Optional

from mantis_rig.hardware.device_interfaces import DaqConfig
from mantis_sim.errors import InputError

from ..contract import (
    CAMERA_NODE,
    DEFAULT_SCENE,
    DEFAULT_SERIAL_PORT,
    DEFAULT_TRIGGER_OUTPUT,
    FORCE_CEILING_NAME,
    FORCE_GUARD_NODES,
    LOADCELL_NODE,
    SIM_WORLD_NODE,
    STAGE_NODE,
    SUPERVISOR_NODE,
)
from ..trial.safety_limits import FORCE_CEILING_DEFAULT_N, FORCE_CEILING_RANGE_N

#: What the Futek LSB302 + IAA100 at rest should read with the tendon slack, untared: the
#: amplifier's zero within 1 N, noise within 0.05 N rms at 20 kS/s (±10 V range). Measure yours
#: (docs/commissioning.md) and put it in the params file's `doctor:` section.
EXPECTED_NOISE_N = 0.05
EXPECTED_OFFSET_N = 1.0


class ParamsError(InputError):
    """The parameters file cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class RigParams:
    source: str = 'defaults'
    serial_port: str = DEFAULT_SERIAL_PORT
    stage_serial_number: str = ''
    counts_per_mm: Optional[float] = None
    channel: str = DaqConfig.channel
    sample_rate_hz: float = DaqConfig.sample_rate_hz
    newtons_per_volt: float = DaqConfig.newtons_per_volt
    block_size: int = 200
    input_range_v: float = DaqConfig.input_range_v
    trigger_output: str = DEFAULT_TRIGGER_OUTPUT
    force_ceiling_n: float = FORCE_CEILING_DEFAULT_N
    out: str = 'trials'
    scene: str = DEFAULT_SCENE
    scene_overrides: tuple = field(default=())
    seed: int = 0
    expected_noise_n: float = EXPECTED_NOISE_N
    expected_offset_n: float = EXPECTED_OFFSET_N

    def daq_config(self) -> DaqConfig:
        return DaqConfig(channel=self.channel, sample_rate_hz=self.sample_rate_hz,
                         input_range_v=self.input_range_v,
                         newtons_per_volt=self.newtons_per_volt, block_size=self.block_size)


# parameter -> (the sections it is read from, in order of precedence; the RigParams field)
_KEYS = {
    'serial_port': ((STAGE_NODE,), 'serial_port', str),
    'stage_serial_number': ((STAGE_NODE,), 'stage_serial_number', str),
    'counts_per_mm': ((STAGE_NODE,), 'counts_per_mm', float),
    'channel': ((LOADCELL_NODE,), 'channel', str),
    'sample_rate_hz': ((LOADCELL_NODE,), 'sample_rate_hz', float),
    'newtons_per_volt': ((LOADCELL_NODE,), 'newtons_per_volt', float),
    'block_size': ((LOADCELL_NODE,), 'block_size', int),
    'lines': ((CAMERA_NODE,), 'trigger_output', str),
    FORCE_CEILING_NAME: ((SUPERVISOR_NODE, *FORCE_GUARD_NODES), FORCE_CEILING_NAME, float),
    'out': ((SUPERVISOR_NODE,), 'out', str),
    'scene': ((SUPERVISOR_NODE, SIM_WORLD_NODE, STAGE_NODE), 'scene', str),
    'set': ((SIM_WORLD_NODE, LOADCELL_NODE), 'scene_overrides', list),
    'seed': ((LOADCELL_NODE, SIM_WORLD_NODE), 'seed', int),
}
_DOCTOR_KEYS = {'expected_noise_n': float, 'expected_offset_n': float}


def _typed(path, where, key, value, kind):
    if kind is str:
        if isinstance(value, (bool, list, dict)) or value is None:
            raise ParamsError(f'{path}: {where}.{key} = {value!r} must be a string')
        return str(value)
    if kind is list:
        if not isinstance(value, list):
            raise ParamsError(f'{path}: {where}.{key} = {value!r} must be a list')
        return tuple(str(item) for item in value if item)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (
            kind is int and not isinstance(value, int)):
        raise ParamsError(f'{path}: {where}.{key} = {value!r} must be '
                          f'{"an integer" if kind is int else "a number"}')
    if kind is float and not math.isfinite(value):
        raise ParamsError(f'{path}: {where}.{key} = {value!r} must be finite')
    return kind(value)


def load_params(path: Optional[Path]) -> RigParams:
    """RigParams from a ROS 2 parameters file (None: the stack's defaults); ParamsError for a
    file that cannot be read or a value of the wrong kind or out of range."""
    if path is None:
        return RigParams()
    import yaml
    try:
        document = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
    except OSError as exc:
        raise ParamsError(f'{path}: cannot read the parameters file: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        raise ParamsError(f'{path}: not YAML: {" ".join(str(exc).split())}') from None
    if document is None:
        document = {}
    if not isinstance(document, dict):
        raise ParamsError(f'{path}: expected a mapping of node name -> ros__parameters')
    sections = {}
    for name, section in document.items():
        if name == 'doctor':
            continue
        if not isinstance(section, dict) or not isinstance(
                section.get('ros__parameters', {}), dict):
            raise ParamsError(f'{path}: section {name!r} must hold a ros__parameters mapping')
        sections[str(name).strip('/')] = section.get('ros__parameters', {}) or {}
    values = {}
    for key, (owners, attribute, kind) in _KEYS.items():
        for owner in owners + ('**',):
            section = sections.get(owner, {})
            if key in section:
                values[attribute] = _typed(path, owner, key, section[key], kind)
                break
    doctor = document.get('doctor') or {}
    if not isinstance(doctor, dict):
        raise ParamsError(f'{path}: section doctor must be a mapping')
    for key, value in doctor.items():
        if key not in _DOCTOR_KEYS:
            raise ParamsError(f'{path}: doctor.{key} is not a doctor setting; known: '
                              f'{", ".join(_DOCTOR_KEYS)}')
        number = _typed(path, 'doctor', key, value, _DOCTOR_KEYS[key])
        if not number > 0:
            raise ParamsError(f'{path}: doctor.{key} = {value!r} must be > 0')
        values[key] = number
    params = replace(RigParams(source=str(path)), **values)
    low, high = FORCE_CEILING_RANGE_N
    if not low <= params.force_ceiling_n <= high:
        raise ParamsError(f'{path}: {FORCE_CEILING_NAME} = {params.force_ceiling_n:g} N is outside '
                          f'[{low:g}, {high:g}] N (mantis_rig/trial/safety_limits.py)')
    if params.counts_per_mm is not None and not 1e3 <= params.counts_per_mm <= 1e6:
        raise ParamsError(f'{path}: {STAGE_NODE}.counts_per_mm = {params.counts_per_mm:g} is '
                          f'outside [1000, 1000000]')
    return params


__all__ = ['EXPECTED_NOISE_N', 'EXPECTED_OFFSET_N', 'ParamsError', 'RigParams', 'load_params']
