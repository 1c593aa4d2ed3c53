"""A Phantom ``.cine``: the camera's own file (``docs/tracking_video.md``, "Reading
recordings").

The headers (CINEFILEHEADER, BITMAPINFOHEADER, SETUP) are read with pycine-lite's ctypes
structures, and its unpacking and linearisation of packed 10-bit pictures are used as they
are. Hand-written here, for what it does not do as needed: the pictures of 8- and 16-bit files
(views into a memory map of the file, unaltered, no copy (:mod:`.frame_io`): pycine-lite
rescales every picture to uint16 through float64), and the time stamps (tagged block 1002,
one TIME64 per frame), taken from the trigger in exact integer arithmetic (pycine-lite's float
seconds since 1970 keep 0.24 µs). Only the SETUP's early fields are used (image size,
FrameRate, ShutterNs, RealBPP): the two readers evaluated disagree on where its late ones sit.
"""
from __future__ import annotations

from collections.abc import Iterator
import ctypes
import math
import os
from pathlib import Path
import struct

import numpy as np

from .frame_io import MappedFile, picture
from .recording_base import Frame, Recording

# biCompression of a packed 10-bit picture (Phantom "P10"), and of packed 12-bit ("P12L").
P10 = 256
P12L = 1024
TAG_TIME = 1002
TAG_EXPOSURE = 1003
_FRACTION = 2.0 ** -32
_ANNOTATION = struct.Struct('<II')


class CineRecording(Recording):
    """A .cine file's frames, numbered from the trigger, with their recorded times."""

    def __init__(self, path, rate_hz: float | None = None):
        from pycine import cine
        self.path = Path(path)
        try:
            self._fd = os.open(self.path, os.O_RDONLY)
        except OSError as exc:
            raise self._bad(f'cannot read the .cine ({exc.strerror})') from None
        try:
            self._file_bytes = os.fstat(self._fd).st_size
            self._mapped = MappedFile(self._fd, self._file_bytes)
            head = self._read(0, ctypes.sizeof(cine.CINEFILEHEADER), 'the file header')
            header = cine.CINEFILEHEADER.from_buffer_copy(head)
            if head[:2] != b'CI':
                raise self._bad('not a .cine (it does not start with "CI")')
            bmp = cine.BITMAPINFOHEADER.from_buffer_copy(self._read(
                header.OffImageHeader, ctypes.sizeof(cine.BITMAPINFOHEADER), 'the image header'))
            setup = self._setup(cine, header.OffSetup)
            self._layout(header, bmp, setup)
            self._times(header, setup)
        except BaseException:
            os.close(self._fd)
            raise
        if rate_hz is not None and abs(rate_hz - self.rate_hz) > 1e-6 * self.rate_hz:
            os.close(self._fd)
            raise self._bad(f'--rate {rate_hz:g} contradicts the .cine header\'s '
                            f'{self.rate_hz:g} frames/s')

    # ------------------------------------------------------------------------ the headers
    def _setup(self, cine, offset: int):
        """The SETUP, as far as the file holds it (its late fields are not used)."""
        size = ctypes.sizeof(cine.SETUP)
        raw = os.pread(self._fd, size, offset)
        if len(raw) < 1000:
            raise self._bad('truncated in the SETUP header')
        return cine.SETUP.from_buffer_copy(raw.ljust(size, b'\0'))

    def _layout(self, header, bmp, setup) -> None:
        self.width, self.height = int(bmp.biWidth), abs(int(bmp.biHeight))
        self._bottom_up = bmp.biHeight > 0
        if not (0 < self.width <= 1 << 16 and 0 < self.height <= 1 << 16):
            raise self._bad(f'image size {bmp.biWidth}x{bmp.biHeight} in its header')
        self.frame_count = int(header.ImageCount)
        self.first_number = int(header.FirstImageNo)
        self._compression = int(bmp.biCompression)
        bits = int(bmp.biBitCount)
        if self._compression == 0 and bits in (8, 16):
            self._dtype = np.dtype(np.uint8 if bits == 8 else '<u2')
            self._row_bytes = self.width * self._dtype.itemsize
            self.bit_depth = 8 if bits == 8 else int(setup.RealBPP or 16)
        elif self._compression == P10:
            self._row_bytes = self.width * 10 // 8
            self.bit_depth = 12            # the linearisation's range
        else:
            raise self._bad(f'a picture format this reader does not know (biCompression '
                            f'{self._compression}, {bits} bits a pixel)')
        self._image_bytes = self._row_bytes * self.height
        count = self.frame_count
        raw = self._read(header.OffImageOffsets, 8 * count, 'the image offsets')
        self._offsets = np.frombuffer(raw, '<i8')
        self.rate_hz = float(setup.FrameRate)
        self.rate_source = 'the .cine header'
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise self._bad(f'frame rate {self.rate_hz:g} in its SETUP header')
        self.exposure_s = setup.ShutterNs * 1e-9 if setup.ShutterNs else math.nan
        self.trigger_index = (-self.first_number
                              if 0 <= -self.first_number < self.frame_count else None)

    def _times(self, header, setup) -> None:
        """Each frame's time from the trigger (s), from tagged block 1002; index / rate where
        the file has none."""
        self._time_s = None
        trigger = (int(header.TriggerTime.seconds) << 32) | int(header.TriggerTime.fractions)
        position = header.OffSetup + setup.Length
        while position + 8 <= header.OffImageOffsets:
            size, tag = np.frombuffer(self._read(position, 8, 'a tagged block'), '<u4', 2)
            size, tag = int(size), int(tag) & 0xFFFF
            if size < 8:
                raise self._bad(f'a tagged block of {size} bytes at byte {position}')
            if tag == TAG_TIME and size - 8 >= 8 * self.frame_count:
                stamps = np.frombuffer(self._read(position + 8, 8 * self.frame_count,
                                                  'the time stamps'), '<u4').reshape(-1, 2)
                ticks = (stamps[:, 1].astype(np.int64) << 32) | stamps[:, 0].astype(np.int64)
                self._time_s = (ticks - trigger) * _FRACTION
            position += size

    def _read(self, offset: int, size: int, what: str) -> bytes:
        raw = os.pread(self._fd, size, offset) if offset >= 0 else b''
        if len(raw) < size:
            raise self._bad(f'truncated in {what} (byte {offset} + {size} of '
                            f'{self._file_bytes})')
        return raw

    # ------------------------------------------------------------------------ the frames
    def _frames(self, first: int, last: int) -> Iterator[Frame]:
        for k in range(first, last):
            number = self.first_number + k
            yield Frame(number, self.frame_time_s(k), self._image(k))

    def frame_time_s(self, position: int) -> float:
        """The time from the trigger (s) of the frame at ``position`` in the file."""
        if self._time_s is not None:
            return float(self._time_s[position])
        return (self.first_number + position) / self.rate_hz

    def _image(self, k: int) -> np.ndarray:
        if self._fd < 0:
            raise self._bad('read after close()')
        offset = int(self._offsets[k])
        head = self._mapped.view(offset, 8) if offset > 0 else None
        if head is None:
            raise self._bad(f'truncated: its picture at byte {offset} is beyond the file '
                            f'({self._file_bytes} bytes)', k)
        annotation, stated = _ANNOTATION.unpack_from(head)
        if annotation < 8:
            raise self._bad(f'damaged: an annotation of {annotation} bytes', k)
        if annotation > 8:       # the image's size ends the annotation
            stated = struct.unpack('<I', os.pread(self._fd, 4, offset + annotation - 4)
                                   .ljust(4, b'\0'))[0]
        if stated != self._image_bytes:
            raise self._bad(f'its picture is {stated} bytes, the recording\'s '
                            f'{self.width}x{self.height} frames are {self._image_bytes}', k)
        start = offset + annotation
        if self._compression == P10:
            return self._p10(start, k)
        image = picture(self._mapped, start, self.height, self._row_bytes, self._dtype,
                        self.width, self._bottom_up)
        if image is None:
            raise self._bad('truncated in its picture', k)
        return image

    def _p10(self, start: int, k: int) -> np.ndarray:
        from pycine.linLUT import linLUT
        from pycine.raw import unpack_10bit
        raw = os.pread(self._fd, self._image_bytes, start)
        if len(raw) < self._image_bytes:
            raise self._bad('truncated in its picture', k)
        image = np.asarray(linLUT, np.uint16)[unpack_10bit(raw, self.width, self.height)]
        return np.ascontiguousarray(image[::-1]) if self._bottom_up else image

    def close(self) -> None:
        if self._fd >= 0:
            self._mapped.close()
            os.close(self._fd)
            self._fd = -1


def cine_rate_hz(path) -> float:
    """The frame rate a .cine's header states (for an .avi exported from it)."""
    with CineRecording(path) as rec:
        return rec.rate_hz
