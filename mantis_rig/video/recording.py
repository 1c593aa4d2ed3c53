"""The recordings' one way in: :func:`open_recording` reads a ``.cine``, an ``.avi``, a folder
of TIFF or PNG frames, or one picture, frame by frame (``docs/tracking_video.md``, "Reading
recordings").

The rate: a .cine states its own (``--rate`` must then agree). An .avi's playback rate is not
the recording's, so its rate (and a folder's) is, in this order, the one given (``--rate``),
that of a ``.cine`` of the same name beside it, or the one the trial's name carries
(``..._19kfps_...``); else it is refused, asking for ``--rate``. One picture needs none.
``Recording.rate_source`` says which was used.
"""
from __future__ import annotations

import math
from pathlib import Path
import re

from mantis_rig.video.recording_error import RecordingError

from .recording_base import Frame, Recording
from .stills import PICTURE_SUFFIXES, StillFrames, picture_files

__all__ = ['Frame', 'Recording', 'RecordingError', 'open_recording', 'rate_from_name']

_RATE_IN_NAME = re.compile(r'(?<![0-9a-z])(\d+(?:[.p]\d+)?)\s*kfps', re.IGNORECASE)


def open_recording(path, rate_hz: float | None = None) -> Recording:
    """The recording at ``path`` (``rate_hz``: the recording's frames per second, --rate)."""
    path = Path(path)
    if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
        raise RecordingError(f'--rate {rate_hz!r}: not a positive number of frames per second')
    if not path.exists():
        raise RecordingError(f'{path}: no such file or folder')
    suffix = path.suffix.lower()
    if suffix == '.cine':
        from .cine import CineRecording
        return CineRecording(path, rate_hz)
    if path.is_dir():
        files = picture_files(path)
        rate, source = _rate(path, rate_hz, what='a folder of frames')
        return StillFrames(path, files, rate, source)
    if suffix == '.avi':
        from .avi import open_avi
        rate, source = _rate(path, rate_hz, what='an .avi')
        return open_avi(path, rate, source)
    if suffix in PICTURE_SUFFIXES:
        if rate_hz is not None:
            rate, source = rate_hz, '--rate'
        else:
            rate = rate_from_name(path.stem)
            source = (f"the trial's name ({_rate_words(path.stem)})" if rate
                      else 'none (one picture)')
        return StillFrames(path, [path], rate, source)
    raise RecordingError(f'{path}: not a recording this reads (.cine, .avi, a folder of TIFF '
                         'or PNG frames, or one .png/.tif picture)')


def rate_from_name(name: str) -> float | None:
    """Frames per second a trial's name carries (``111319_11kfps_T_...`` -> 11000)."""
    m = _RATE_IN_NAME.search(name or '')
    return float(m.group(1).replace('p', '.').replace('P', '.')) * 1000.0 if m else None


def _rate_words(name: str) -> str:
    return _RATE_IN_NAME.search(name).group(0)


def _rate(path: Path, rate_hz: float | None, what: str) -> tuple[float, str]:
    if rate_hz is not None:
        return float(rate_hz), '--rate'
    beside = _cine_beside(path)
    if beside is not None:
        from .cine import cine_rate_hz
        return cine_rate_hz(beside), 'the .cine beside it'
    for name in (path.stem, path.parent.name) if path.is_file() else (path.name,):
        rate = rate_from_name(name)
        if rate:
            return rate, f"the trial's name ({_rate_words(name)})"
    raise RecordingError(f'{path}: the recording\'s rate is unknown: {what} carries only a '
                         'playback rate, no .cine of the same name is beside it and its name '
                         'holds none (like "19kfps"): give it with --rate FRAMES_PER_S')


def _cine_beside(path: Path) -> Path | None:
    if path.is_dir():
        candidates = [path.with_suffix('.cine'), path / f'{path.name}.cine']
    else:
        candidates = [path.with_suffix('.cine'), path.with_suffix('.CINE')]
    return next((c for c in candidates if c.is_file()), None)
