"""The recordings' one bad-input error."""
from __future__ import annotations

from mantis_sim.errors import InputError


class RecordingError(InputError):
    """A recording that cannot be read: truncated or damaged, a frame of another size, an
    unknown format, a rate that cannot be found. The message names the file and, where one
    frame is at fault, its index; frames read before it have already been yielded."""
