"""The rig's own faults, and the exit statuses that end `mantis`.

- Bad input (a file, a field, a value or an option that cannot be used: ConditionError,
  BagError, TrackFormatError, SceneError, ParameterError ...) is an
  :class:`mantis_sim.errors.InputError`, defined there once and imported from there by every
  module of both packages (not from here: test/unit/test_layers.py). `mantis` prints it in one
  line and exits :data:`USAGE_ERROR`. It is not a ValueError: an ``except ValueError`` around a
  library call does not swallow it.
- :class:`RigFault`: the rig or its node stack failed (a device refused, timed out or
  vanished, a node process died, the log could not be written). `mantis` prints it in one line
  and exits :data:`RIG_FAULT`; the stage has been stopped by then (the node or the command
  that met the fault stops it before raising further).

Anything else that reaches `mantis` is a bug and keeps its traceback. mantis_sim's own
SimulationError (a run that cannot be integrated) exits 1.
"""

USAGE_ERROR = 2      # bad input (an InputError) or a bad command line (argparse's own status)
RIG_FAULT = 3        # a RigFault: a device or the node stack failed


class RigFault(Exception):
    """A device or the node stack failed; the message says which and how."""


class DeviceError(RigFault):
    """A device refused, timed out, replied with garbage or vanished. The message says which."""


class SafetyLimitError(DeviceError):
    """A safety limit (travel, speed, force ceiling) stopped the device."""


class ConfigurationError(RigFault):
    """A setting is outside what the device or the rig's safety limits allow."""


class StackError(RigFault):
    """A node of the stack could not be started or has died."""


class BagClosedError(RigFault):
    """The bag was written to after close()."""


__all__ = ['BagClosedError', 'ConfigurationError', 'DeviceError', 'RIG_FAULT', 'RigFault',
           'SafetyLimitError', 'StackError', 'USAGE_ERROR']
