"""Uncompressed pictures of a long file, with flat memory and no copy: :class:`MappedFile`.

A frame is a numpy view straight into a memory map of the file (a private, copy-on-write map:
the consumer may keep it, and even write into it, without touching the file). The file is
mapped a window of ``WINDOW_BYTES`` at a time; moving on drops the old window, which is
unmapped as soon as no frame taken from it is still held: the process's resident memory is
then one window (the file's pages stay in the page cache, shared, and are no longer counted
in the process), whatever the recording's length. Only the pages a consumer touches are read:
the tracker, which looks at a few small windows per frame, reads a fraction of each picture.

A bottom-up picture (a .cine's, a DIB .avi's) is returned as the rows reversed, a view with a
negative row stride: numpy and OpenCV take such views as they are.

Measured on this machine, 20,000 frames of 512 x 512 8-bit in the page cache: one ``preadv``
per frame into a fresh array ran near 20,000 to 28,000 frames/s (the copy of each picture is
most of it); a view per frame costs a few microseconds, and touching every page of every
frame runs near the memory's speed. A file not in the page cache reads at the disk's speed
(here near 500 MB/s, 1,900 frames/s), whichever way.
"""
from __future__ import annotations

import mmap
import os

import numpy as np

# Mapped at a time; a picture larger than this gets a window of its own size.
WINDOW_BYTES = 8 << 20


class MappedFile:
    """A file read as memory-mapped windows (see the module docstring). ``close()`` drops the
    current window; frames already taken stay valid."""

    def __init__(self, fd: int, file_bytes: int):
        self._fd = fd
        self.file_bytes = file_bytes
        self._map: mmap.mmap | None = None
        self._start = self._end = 0

    def view(self, offset: int, size: int) -> memoryview | None:
        """``size`` bytes from ``offset`` as a buffer into the map (no copy), or None if the
        file ends before them."""
        end = offset + size
        if offset < 0 or end > self.file_bytes:
            return None
        if not (self._start <= offset and end <= self._end):
            self._remap(offset, size)
        return memoryview(self._map)[offset - self._start:end - self._start]

    def _remap(self, offset: int, size: int) -> None:
        start = offset - offset % mmap.ALLOCATIONGRANULARITY
        length = min(max(WINDOW_BYTES, offset + size - start), self.file_bytes - start)
        # Dropped, not closed: frames still held keep their window mapped until they go.
        self._map = mmap.mmap(self._fd, length, access=mmap.ACCESS_COPY, offset=start)
        self._start, self._end = start, start + length

    def close(self) -> None:
        self._map = None
        self._start = self._end = 0


def picture(mapped: MappedFile, offset: int, height: int, row_bytes: int, dtype, width: int,
            bottom_up: bool, row_stride: int | None = None) -> np.ndarray | None:
    """A (height, width) picture of ``dtype`` at byte ``offset``, row 0 at the top: a view into
    the map; rows ``row_stride`` bytes apart in the file (a DIB pads them to 4 bytes), the
    bottom row first if ``bottom_up``. None if the file ends before the picture does."""
    stride = row_stride or row_bytes
    buffer = mapped.view(offset, height * stride)
    if buffer is None:
        return None
    raw = np.frombuffer(buffer, np.uint8).reshape(height, stride)
    pixels = (raw if stride == row_bytes else raw[:, :row_bytes]).view(dtype)
    pixels = pixels.reshape(height, width)
    return pixels[::-1] if bottom_up else pixels


def read_rows(fd: int, offset: int, height: int, row_bytes: int, dtype, width: int,
              bottom_up: bool, row_stride: int | None = None) -> np.ndarray | None:
    """As :func:`picture`, but read with one ``preadv`` into a fresh array (for a file that
    cannot be mapped)."""
    stride = row_stride or row_bytes
    raw = np.empty((height, stride), np.uint8)
    if os.preadv(fd, [raw], offset) < raw.nbytes:
        return None
    pixels = (raw if stride == row_bytes else raw[:, :row_bytes]).view(dtype)
    pixels = pixels.reshape(height, width)
    return pixels[::-1] if bottom_up else pixels
