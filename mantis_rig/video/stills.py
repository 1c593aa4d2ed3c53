"""A folder of TIFF or PNG frames (in natural order: ``f2`` before ``f10``), or one picture
(a recording of one frame). Colour pictures (RGB, RGBA: the lab's screenshots) become grey;
16-bit ones stay 16-bit."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
import re

import numpy as np

from mantis_rig.video.recording_error import RecordingError

from .recording_base import Frame, Recording

PICTURE_SUFFIXES = ('.png', '.tif', '.tiff')


def natural_key(path: Path) -> list:
    return [int(part) if part.isdigit() else part.lower()
            for part in re.split(r'(\d+)', path.name)]


def picture_files(folder: Path) -> list[Path]:
    """The folder's TIFF and PNG files, naturally sorted."""
    return sorted((p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in PICTURE_SUFFIXES), key=natural_key)


class StillFrames(Recording):
    """Pictures as the frames of one recording (a folder's, or a single file's)."""

    def __init__(self, path, files: list[Path], rate_hz, rate_source: str):
        self.path = Path(path)
        if not files:
            raise RecordingError(f'{self.path}: no TIFF or PNG frames in it')
        self._files = files
        self.rate_hz, self.rate_source = rate_hz, rate_source
        first = read_picture(files[0], 0)
        self.height, self.width = first.shape
        self.bit_depth = 8 if first.dtype == np.uint8 else 16
        self.frame_count = len(files)

    def _frames(self, first: int, last: int) -> Iterator[Frame]:
        for position in range(first, last):
            image = read_picture(self._files[position], position)
            if image.shape != (self.height, self.width):
                raise RecordingError(
                    f'{self._files[position]}: frame {position}: {image.shape[1]}x'
                    f'{image.shape[0]} pixels, the recording\'s frames are {self.width}x'
                    f'{self.height}')
            yield Frame(position, self._time_s(position), image)


def read_picture(path: Path, position: int) -> np.ndarray:
    """One picture as 2-D grey uint8 or uint16."""
    import cv2
    image = None
    if path.stat().st_size:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise RecordingError(f'{path}: frame {position}: not a picture OpenCV can read')
    if image.dtype not in (np.uint8, np.uint16):
        raise RecordingError(f'{path}: frame {position}: {image.dtype} pixels (expected 8- '
                             'or 16-bit)')
    if image.ndim == 3:
        if image.shape[2] == 1:
            image = image[:, :, 0]
        else:
            code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
            image = cv2.cvtColor(image, code)
    return image
