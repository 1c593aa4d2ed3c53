"""A minimal valid Phantom ``.cine`` writer (8- and 16-bit grey, uncompressed), streamed.

The file, per the Phantom cine file format: CINEFILEHEADER (44 bytes), BITMAPINFOHEADER (40),
SETUP (the fields below; ``Length`` bytes), tagged blocks (1002: a TIME64 per frame, 1003: the
exposure per frame), the image offsets (int64 per frame), then each image: an annotation of 8
bytes (its own size, then the image's) and the pixels, bottom row first (a DIB). Frames are
numbered from the trigger: the first is ``first_number`` (negative: frames before it); frame
n's time stamp is the trigger's plus n / rate. Written independently of the reader
(the rig's video package), so that a round trip tests the two against each other.
"""
from __future__ import annotations

import datetime
import math
from pathlib import Path
import struct

import numpy as np

__all__ = ['CineWriter']

HEADER_BYTES = 44
BITMAP_BYTES = 40
# SETUP's size as pycine-lite's structure has it; only its early fields are written.
SETUP_BYTES = 13484
# Offsets of the SETUP fields written (bytes from its start; the format's packed layout).
_SETUP_FIELDS = {'FrameRate16': (0, '<H'), 'Shutter16': (2, '<H'), 'PostTrigger16': (4, '<H'),
                 'Mark': (140, '2s'), 'Length': (142, '<H'), 'ImWidth': (737, '<H'),
                 'ImHeight': (739, '<H'), 'FrameRate': (768, '<I'), 'PostTrigger': (780, '<I'),
                 'RealBPP': (896, '<I'), 'ShutterNs': (1568, '<I'), 'ImWidthAcq': (1588, '<I'),
                 'ImHeightAcq': (1592, '<I'), 'BlackLevel': (5732, '<i'),
                 'WhiteLevel': (5736, '<i')}
# fDecimation and the rate as a double, near the SETUP's end: at both places the readers look
# for them (AMETEK's cinereader: strings of 256 bytes before them; pycine-lite: of 1024).
_LATE_FIELDS = {'fDecimation': ((10388, 13460), '<f'), 'dFrameRate': ((10400, 13472), '<d')}
TAG_TIME = 1002
TAG_EXPOSURE = 1003
ANNOTATION_BYTES = 8


class CineWriter:
    """A .cine being written frame by frame (``write``); ``close`` checks that every frame
    announced came. A context manager."""

    def __init__(self, path, width: int, height: int, frame_count: int, rate_hz: float,
                 first_number: int = 0, bit_depth: int = 8, exposure_s: float | None = None,
                 trigger_time: datetime.datetime | None = None):
        if bit_depth not in (8, 16) and not 8 < bit_depth <= 16:
            raise ValueError(f'bit depth {bit_depth}: 8, or up to 16 in 16-bit pixels')
        self.path = Path(path)
        self.width, self.height, self.frame_count = int(width), int(height), int(frame_count)
        self.rate_hz = float(rate_hz)
        self.first_number = int(first_number)
        self._dtype = np.dtype(np.uint8 if bit_depth == 8 else '<u2')
        self._image_bytes = self.width * self.height * self._dtype.itemsize
        exposure_s = (1.0 / rate_hz - 20e-6) if exposure_s is None else exposure_s
        when = trigger_time or datetime.datetime(2026, 1, 1, tzinfo=datetime.UTC)
        trigger_ticks = int(when.timestamp()) << 32
        self._written = 0
        self._file = open(self.path, 'wb')  # noqa: SIM115 - closed in close()
        blocks = self._tagged_blocks(trigger_ticks, exposure_s)
        offsets_at = HEADER_BYTES + BITMAP_BYTES + SETUP_BYTES + len(blocks)
        first_image = offsets_at + 8 * self.frame_count
        step = ANNOTATION_BYTES + self._image_bytes
        offsets = first_image + step * np.arange(self.frame_count, dtype='<i8')
        self._file.write(struct.pack(
            '<2sHHHiIiIIIIII', b'CI', HEADER_BYTES, 0, 1, self.first_number, self.frame_count,
            self.first_number, self.frame_count, HEADER_BYTES, HEADER_BYTES + BITMAP_BYTES,
            offsets_at, trigger_ticks & 0xFFFFFFFF, trigger_ticks >> 32))
        # biHeight > 0: bottom-up rows, as the camera writes them.
        self._file.write(struct.pack('<IiiHHIIiiII', BITMAP_BYTES, self.width, self.height, 1,
                                     8 * self._dtype.itemsize, 0, self._image_bytes,
                                     0, 0, 0, 0))
        self._file.write(self._setup(bit_depth, exposure_s))
        self._file.write(blocks)
        self._file.write(offsets.tobytes())

    def _setup(self, bit_depth: int, exposure_s: float) -> bytes:
        setup = bytearray(SETUP_BYTES)
        post = self.frame_count + self.first_number
        values = {'FrameRate16': min(int(round(self.rate_hz)), 0xFFFF),
                  'Shutter16': min(int(round(exposure_s * 1e6)), 0xFFFF),
                  'PostTrigger16': min(max(post, 0), 0xFFFF), 'Mark': b'ST',
                  'Length': SETUP_BYTES, 'ImWidth': self.width, 'ImHeight': self.height,
                  'FrameRate': int(round(self.rate_hz)), 'PostTrigger': max(post, 0),
                  'RealBPP': bit_depth, 'ShutterNs': int(round(exposure_s * 1e9)),
                  'ImWidthAcq': self.width, 'ImHeightAcq': self.height, 'BlackLevel': 0,
                  'WhiteLevel': (1 << bit_depth) - 1}
        for name, value in values.items():
            offset, fmt = _SETUP_FIELDS[name]
            struct.pack_into(fmt, setup, offset, value)
        for name, value in (('fDecimation', 1.0), ('dFrameRate', self.rate_hz)):
            offsets, fmt = _LATE_FIELDS[name]
            for offset in offsets:
                struct.pack_into(fmt, setup, offset, value)
        return bytes(setup)

    def _tagged_blocks(self, trigger_ticks: int, exposure_s: float) -> bytes:
        numbers = self.first_number + np.arange(self.frame_count, dtype=np.int64)
        steps = np.floor(numbers * (2.0 ** 32 / self.rate_hz) + 0.5)    # as frame_time_s
        ticks = trigger_ticks + steps.astype(np.int64)
        stamps = np.empty((self.frame_count, 2), '<u4')
        stamps[:, 0] = ticks & 0xFFFFFFFF          # TIME64: fractions of a second, then seconds
        stamps[:, 1] = ticks >> 32
        time_block = struct.pack('<IHH', 8 + stamps.nbytes, TAG_TIME, 0) + stamps.tobytes()
        exposure = np.full(self.frame_count, min(round(exposure_s * 2.0 ** 32), 2 ** 32 - 1),
                           '<u4')
        exposure_block = (struct.pack('<IHH', 8 + exposure.nbytes, TAG_EXPOSURE, 0)
                          + exposure.tobytes())
        return time_block + exposure_block

    def write(self, image: np.ndarray) -> None:
        """The next frame: (height, width), row 0 at the top, uint8 (8-bit) or uint16."""
        image = np.asarray(image)
        if image.shape != (self.height, self.width):
            raise ValueError(f'frame {self._written}: shape {image.shape}, the file\'s '
                             f'{(self.height, self.width)}')
        if self._written >= self.frame_count:
            raise ValueError(f'more than the {self.frame_count} frames announced')
        self._file.write(struct.pack('<II', ANNOTATION_BYTES, self._image_bytes))
        self._file.write(np.ascontiguousarray(image[::-1], self._dtype).tobytes())
        self._written += 1

    def close(self) -> None:
        if self._file.closed:
            return
        self._file.close()
        if self._written != self.frame_count:
            raise ValueError(f'{self.path}: {self._written} frames written of the '
                             f'{self.frame_count} announced')

    def __enter__(self) -> CineWriter:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is None:
            self.close()
        else:
            self._file.close()


def frame_time_s(number: int, rate_hz: float) -> float:
    """The time from the trigger (s) the writer stamps on frame ``number``, as the reader
    reads it back (rounded to the TIME64's 2^-32 s)."""
    return math.floor(number * (2.0 ** 32 / rate_hz) + 0.5) * 2.0 ** -32
