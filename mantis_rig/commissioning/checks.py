"""`mantis doctor`'s checks in their order: the ROS environment and the disk, then the devices
(hardware: the NI DAQ's devices first), the load cell, the camera trigger, the stage and, with
--move, its guarded jog. Every device is closed, every DAQ task, thread and the simulated world
ended, before run_checks returns, whatever failed."""
from __future__ import annotations

from pathlib import Path

from .check_report import Options, Report
from .device_checks import check_camera, check_daq_devices, check_loadcell
from .doctor_rigs import HardwareRig, SimulatedDevices
from .environment_checks import check_disk, check_ros_environment
from .rig_params import RigParams
from .stage_checks import check_stage


def run_checks(options: Options) -> Report:
    """Every check on options.backend's devices (the stack's defaults without params)."""
    if options.params is None:
        options.params = RigParams()
    report = Report()
    check_ros_environment(report)
    check_disk(report, Path(options.params.out))
    if options.backend == 'sim':
        with SimulatedDevices(options) as rig:
            check_devices(report, options, rig)
    else:
        check_devices(report, options, HardwareRig(options))
    return report


def check_devices(report: Report, options: Options, rig) -> None:
    daq_device = None
    if not rig.sim:
        daq_device = check_daq_devices(report, options.params)
    loadcell_ok = check_loadcell(report, options, rig, daq_device)
    check_camera(report, options, rig, daq_device)
    check_stage(report, options, rig, loadcell_ok)


__all__ = ['check_devices', 'run_checks']
