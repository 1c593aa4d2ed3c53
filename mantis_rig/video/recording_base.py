"""What every recording is: :class:`Frame`, and :class:`Recording`, the base of each format's
reader (``cine``, ``avi``, ``stills``); :func:`~.recording.open_recording` chooses one."""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
import math
from pathlib import Path

import numpy as np

from mantis_rig.video.recording_error import RecordingError


@dataclass(frozen=True)
class Frame:
    """One picture of a recording.

    ``index``: the camera's frame number (a .cine's counts from the trigger, negative before
    it; 0, 1, ... for the other formats). ``time_s``: time from the trigger, NaN where unknown
    (an .avi's or a folder's: index / rate, from its first frame). ``image``: 2-D grey, uint8
    or uint16, row 0 at the top, a new array the consumer may keep."""

    index: int
    time_s: float
    image: np.ndarray


class Recording:
    """A recording, read frame by frame (memory does not grow with its length).

    ``rate_hz``: frames per second of the recording (None where unknown: one picture);
    ``rate_source``: where it came from, in words ('the .cine header', '--rate', 'the .cine
    beside it', "the trial's name (19kfps)"). ``trigger_index``: the position in the file
    (0-based) of the trigger frame, None where the format does not record one. ``bit_depth``:
    the significant bits of a pixel (8; 10, 12, 14 or 16 in uint16 pictures)."""

    path: Path
    width: int
    height: int
    frame_count: int
    bit_depth: int
    rate_hz: float | None
    rate_source: str
    trigger_index: int | None = None

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """The frames at positions ``start`` to ``stop`` (0-based positions in the file, not
        camera numbers; ``stop`` None: to the end). A bad frame raises RecordingError naming
        the file and the frame after those before it were yielded."""
        first, last = self._span(start, stop)
        return self._frames(first, last)

    def _frames(self, first: int, last: int) -> Iterator[Frame]:
        raise NotImplementedError

    def close(self) -> None:
        """Release the file (frames already read stay valid)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __len__(self) -> int:
        return self.frame_count

    def __repr__(self) -> str:
        rate = f'{self.rate_hz:g}/s from {self.rate_source}' if self.rate_hz else 'rate unknown'
        return (f'<{type(self).__name__} {self.path.name}: {self.frame_count} frames of '
                f'{self.width}x{self.height}, {self.bit_depth}-bit, {rate}>')

    # ---------------------------------------------------------------------- helpers
    def _span(self, start: int, stop: int | None) -> tuple[int, int]:
        stop = self.frame_count if stop is None else stop
        if not (0 <= start <= stop <= self.frame_count):
            raise ValueError(f'{self.path.name}: frames {start} to {stop} are not within its '
                             f'{self.frame_count} frames')
        return int(start), int(stop)

    def _time_s(self, index: int) -> float:
        return index / self.rate_hz if self.rate_hz else math.nan

    def _bad(self, what: str, position: int | None = None) -> RecordingError:
        where = '' if position is None else f' frame {position}:'
        return RecordingError(f'{self.path}:{where} {what}')

    def _check_size(self, image: np.ndarray, position: int) -> np.ndarray:
        if image.shape != (self.height, self.width):
            raise self._bad(f'{image.shape[1]}x{image.shape[0]} pixels, the recording\'s '
                            f'frames are {self.width}x{self.height}', position)
        return image
