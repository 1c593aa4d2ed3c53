"""An ``.avi``: uncompressed ones read here straight from the file, anything else (lossless
FFV1, ...) decoded by OpenCV.

Uncompressed means what the camera's software and ffmpeg write: 8-bit DIB (``BI_RGB`` with a
palette, rows bottom-up and padded to 4 bytes) or ``Y800``/``GREY`` (top-down), 16-bit ``Y16``;
in RIFF ``AVI `` and, past 1 GB, its OpenDML continuations (``AVIX``). Their frames are found
by walking the ``movi`` lists' chunks (no index needed, so a file cut short still gives the
frames before the cut); each picture is a view into a memory map of the file
(:mod:`.frame_io`: no copy, flat memory).

The .avi's own rate is a playback rate, not the recording's: the caller gives the rate
(:func:`~.recording.open_recording`'s rules).
"""
from __future__ import annotations

from collections.abc import Iterator
import os
from pathlib import Path
import struct

import numpy as np

from .frame_io import MappedFile, picture
from .recording_base import Frame, Recording

_GREY_8 = {b'Y800', b'GREY', b'Y8  ', b'Y8\0\0'}
_GREY_16 = {b'Y16 ', b'Y16\0'}
_VIDEO_CHUNK = ('db', 'dc')


def open_avi(path, rate_hz: float | None, rate_source: str) -> Recording:
    """The .avi's reader: raw if its pictures are uncompressed grey, else OpenCV's."""
    path = Path(path)
    layout = _raw_layout(path)
    if layout is not None:
        return RawAvi(path, layout, rate_hz, rate_source)
    return DecodedAvi(path, rate_hz, rate_source)


class RawAvi(Recording):
    """An uncompressed grey .avi, read from the file."""

    def __init__(self, path: Path, layout: dict, rate_hz, rate_source: str):
        self.path = path
        self.rate_hz, self.rate_source = rate_hz, rate_source
        self.width, self.height = layout['width'], layout['height']
        self.frame_count = layout['frames']
        self.bit_depth = layout['bits']
        self._bottom_up = layout['bottom_up']
        self._dtype = np.dtype(np.uint8 if self.bit_depth == 8 else '<u2')
        self._row_bytes = self.width * self._dtype.itemsize
        self._stride = (self._row_bytes + 3) & ~3 if layout['dib'] else self._row_bytes
        self._image_bytes = self._stride * self.height
        self._palette = layout.get('palette')
        self._stream = layout['stream']
        self._fd = os.open(path, os.O_RDONLY)
        self._file_bytes = os.fstat(self._fd).st_size
        self._mapped = MappedFile(self._fd, self._file_bytes)

    def _frames(self, first: int, last: int) -> Iterator[Frame]:
        position = 0
        if self._fd < 0:
            raise self._bad('read after close()')
        for offset, size in _video_chunks(self._mapped, self._stream):
            if position >= last:
                return
            if position >= first:
                yield Frame(position, self._time_s(position), self._image(offset, size,
                                                                          position))
            position += 1
        if position < last:
            raise self._bad(f'truncated: the file ends after {position} of its '
                            f'{self.frame_count} frames', position)

    def _image(self, offset: int, size: int, position: int) -> np.ndarray:
        if size != self._image_bytes:
            raise self._bad(f'its picture is {size} bytes, the recording\'s {self.width}x'
                            f'{self.height} frames are {self._image_bytes}', position)
        image = picture(self._mapped, offset, self.height, self._row_bytes, self._dtype,
                        self.width, self._bottom_up, self._stride)
        if image is None:
            raise self._bad('truncated in its picture', position)
        return image if self._palette is None else self._palette[image]

    def close(self) -> None:
        if self._fd >= 0:
            self._mapped.close()
            os.close(self._fd)
            self._fd = -1


class DecodedAvi(Recording):
    """A compressed .avi (FFV1, ...) decoded by OpenCV; colour pictures become grey."""

    def __init__(self, path: Path, rate_hz, rate_source: str):
        import cv2
        self.path = path
        self.rate_hz, self.rate_source = rate_hz, rate_source
        self._cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
        if not self._cap.isOpened():
            raise self._bad('not a video OpenCV can decode')
        self._cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        self.width = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        self.height = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        self.frame_count = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if self.width <= 0 or self.height <= 0 or self.frame_count <= 0:
            self._cap.release()
            raise self._bad(f'no pictures ({self.width}x{self.height}, '
                            f'{self.frame_count} frames)')
        self.bit_depth = 8
        self._next = 0

    def _frames(self, first: int, last: int) -> Iterator[Frame]:
        import cv2
        if first != self._next:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, first)
        for position in range(first, last):
            ok, image = self._cap.read()
            if not ok or image is None:
                raise self._bad(f'damaged or truncated: no picture decoded (of the '
                                f'{self.frame_count} its index lists)', position)
            self._next = position + 1
            yield Frame(position, self._time_s(position), self._check_size(_grey(image),
                                                                           position))

    def close(self) -> None:
        self._cap.release()


def _grey(image: np.ndarray) -> np.ndarray:
    import cv2
    if image.ndim == 2:
        return image
    if image.shape[2] == 1:
        return image[:, :, 0]
    code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(image, code)


# ------------------------------------------------------------------------------ RIFF AVI
def _raw_layout(path: Path) -> dict | None:
    """The picture layout of an uncompressed grey .avi, None for any other (compressed,
    colour: OpenCV's); RecordingError for a file that is no AVI at all."""
    from mantis_rig.video.recording_error import RecordingError
    try:
        with open(path, 'rb') as f:
            head = f.read(12)
            if len(head) < 12 or head[:4] != b'RIFF' or head[8:12] != b'AVI ':
                raise RecordingError(f'{path}: not an AVI file (no RIFF AVI header)')
            hdrl = _find_list(f, 12, len(head) + struct.unpack('<I', head[4:8])[0], b'hdrl')
            if hdrl is None:
                raise RecordingError(f'{path}: damaged AVI: no hdrl header list')
            return _stream_layout(f, *hdrl)
    except OSError as exc:
        raise RecordingError(f'{path}: cannot read the .avi ({exc.strerror})') from None


def _find_list(f, start: int, end: int, kind: bytes) -> tuple[int, int] | None:
    """(start, end) of the contents of the first LIST ``kind`` between the two offsets."""
    position = start
    while position + 12 <= end:
        f.seek(position)
        head = f.read(12)
        if len(head) < 8:
            return None
        fourcc, size = head[:4], struct.unpack('<I', head[4:8])[0]
        if fourcc == b'LIST' and head[8:12] == kind:
            return position + 12, position + 8 + size
        position += 8 + size + (size & 1)
    return None


def _stream_layout(f, start: int, end: int) -> dict | None:
    """The first video stream's layout, from the strl lists in hdrl; None unless raw grey."""
    position, stream, frames_total = start, 0, None
    while position + 8 <= end:
        f.seek(position)
        head = f.read(12)
        fourcc, size = head[:4], struct.unpack('<I', head[4:8])[0]
        if fourcc == b'LIST' and head[8:12] == b'strl':
            layout = _strl(f, position + 12, position + 8 + size)
            if layout is not None:
                layout['stream'] = f'{stream:02d}'
                odml = _find_list(f, start, end, b'odml')
                if odml is not None:
                    f.seek(odml[0])
                    dmlh = f.read(12)
                    if dmlh[:4] == b'dmlh':
                        frames_total = struct.unpack('<I', dmlh[8:12])[0]
                if frames_total:
                    layout['frames'] = max(layout['frames'], frames_total)
                return layout if layout.get('raw') else None
            stream += 1
        position += 8 + size + (size & 1)
    return None


def _strl(f, start: int, end: int) -> dict | None:
    """A video stream's strh and strf: its size, length and whether its pictures are raw."""
    layout: dict = {}
    position = start
    while position + 8 <= end:
        f.seek(position)
        fourcc, size = struct.unpack('<4sI', f.read(8))
        body = f.read(min(size, 1 << 16))
        if fourcc == b'strh':
            if body[:4] != b'vids':
                return None
            layout['frames'] = struct.unpack('<I', body[32:36])[0]
        elif fourcc == b'strf' and len(body) >= 40:
            (_, width, height, _, bits, compression, _, _, _, used, _) = struct.unpack(
                '<IiiHHIIiiII', body[:40])
            code = struct.pack('<I', compression)
            layout.update(width=width, height=abs(height), bottom_up=height > 0, bits=bits)
            if compression == 0 and bits == 8:
                colours = used or 256
                palette = np.frombuffer(body[40:40 + 4 * colours], np.uint8).reshape(-1, 4)
                layout.update(raw=True, dib=True, palette=_grey_palette(palette))
            elif code in _GREY_8 or code in _GREY_16:
                # Y800 and its kin are top-down whatever the sign of the height.
                layout.update(raw=True, dib=False, bottom_up=False,
                              bits=8 if code in _GREY_8 else 16)
        position += 8 + size + (size & 1)
    return layout if 'width' in layout else None


def _grey_palette(palette: np.ndarray) -> np.ndarray | None:
    """None for the identity grey palette (the camera's), else a lookup to grey levels."""
    if len(palette) == 256 and np.array_equal(palette[:, 0], np.arange(256)) and np.array_equal(
            palette[:, 0], palette[:, 1]) and np.array_equal(palette[:, 1], palette[:, 2]):
        return None
    lut = np.zeros(256, np.uint8)
    bgr = palette[:, :3].astype(float)
    lut[:len(palette)] = np.round(0.114 * bgr[:, 0] + 0.587 * bgr[:, 1] + 0.299 * bgr[:, 2])
    return lut


def _video_chunks(mapped: MappedFile, stream: str) -> Iterator[tuple[int, int]]:
    """(offset, size) of each picture chunk of ``stream``, walking every RIFF's movi list
    (AVI and OpenDML's AVIX) in order; stops quietly where the file is cut short."""
    tags = {stream.encode() + t.encode() for t in _VIDEO_CHUNK}
    file_bytes = mapped.file_bytes
    riff = 0
    while riff + 12 <= file_bytes:
        head = mapped.view(riff, 12)
        head = None if head is None else bytes(head)    # not a view: the window may go
        if head is None or head[:4] != b'RIFF':
            return
        riff_end = riff + 8 + _U32.unpack_from(head, 4)[0]
        position = riff + 12
        while position + 8 <= min(riff_end, file_bytes):
            fourcc, size = _CHUNK.unpack_from(mapped.view(position, 8))
            if fourcc == b'LIST' and mapped.view(position + 8, 4) == b'movi':
                yield from _movi(mapped, position + 12, position + 8 + size, tags)
            position += 8 + size + (size & 1)
        riff = riff_end + (riff_end & 1)


_U32 = struct.Struct('<I')
_CHUNK = struct.Struct('<4sI')


def _movi(mapped: MappedFile, start: int, end: int, tags: set):
    file_bytes = mapped.file_bytes
    position = start
    while position + 8 <= min(end, file_bytes):
        fourcc, size = _CHUNK.unpack_from(mapped.view(position, 8))
        if fourcc == b'LIST' and mapped.view(position + 8, 4) == b'rec ':
            yield from _movi(mapped, position + 12, position + 8 + size, tags)
        elif fourcc in tags:
            # Cut short inside this picture: yielded all the same, reported as its damage.
            yield position + 8, size
            if position + 8 + size > file_bytes:
                return
        position += 8 + size + (size & 1)
