"""The root of every bad-input error, for mantis_sim and every package built on it.

InputError: a file, a field or a value that cannot be used, or a result it would give that is
physically impossible. Its message names which, and where (the file; the record, topic and log
time; the row; the key). The `mantis` command line reports it in one line and exits 2; any
other exception is a bug and keeps its traceback. It is not a ValueError, so that an
``except ValueError`` around a library call never swallows it. Every module of mantis_sim and
of the packages built on it imports it from here, the one way in (the rig package's errors
module holds the rig's faults, not this; test/unit/test_layers.py).
"""


class InputError(Exception):
    """Bad input, named in the message (see the module docstring)."""


__all__ = ['InputError']
