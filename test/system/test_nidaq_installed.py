"""The NI-DAQmx backends against what is really installed, which starts processes (moved out
of test/unit/test_nidaq.py, whose tests start none): without the nidaqmx package, in a fresh
interpreter; with the real package, whose driver lookup runs programs to find its library."""
from dataclasses import replace
import importlib.util
import os
import subprocess
import sys

import pytest

from mantis_rig.hardware.device_interfaces import DaqConfig, DeviceError
from mantis_rig.hardware.nidaq_force import NidaqForceDaq

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_modules_import_without_nidaqmx():
    code = ("import sys; sys.modules['nidaqmx'] = None\n"
            "import mantis_rig.hardware.nidaq, mantis_rig.hardware.nidaq_force, "
            "mantis_rig.hardware.nidaq_trigger as t\n"
            "t.NidaqCameraTrigger('Dev1/ctr0').close()\n"
            "assert sys.modules['nidaqmx'] is None\n")
    result = subprocess.run([sys.executable, '-c', code], cwd=REPO, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr


CONFIG = DaqConfig(channel='Dev1/ai0', sample_rate_hz=20_000.0, input_range_v=10.0,
                   newtons_per_volt=11.12, offset_v=0.25, block_size=1000)


def real_nidaqmx():
    if importlib.util.find_spec('nidaqmx') is None:
        pytest.skip('nidaqmx is not installed (pip install nidaqmx==1.7.0 to run this check)')
    return importlib.import_module('nidaqmx')


def test_real_nidaqmx_open_failure_is_a_device_error():
    """No NI-DAQmx driver (CI) or no such device (the rig): DeviceError, nothing left open."""
    real_nidaqmx()
    daq = NidaqForceDaq(replace(CONFIG, channel='NoSuchDev9/ai0'))
    with pytest.raises(DeviceError, match='NI-DAQmx|-200220'):
        daq.open()
    daq.close()
