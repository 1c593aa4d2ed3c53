"""A camera calibration as the motion tracker holds it: scale, origin, tilt, handedness.

Pixels are the image's: x right, y down, (0, 0) the centre of the top-left pixel. Millimetres
are the tracker's calibrated frame, with the conventions of ``docs/tracking_export.md`` and the
analysis of the tracks (its right-handed frame): with p the offset from the origin
in the image's axes (y down) divided by the scale, a left-handed calibration at tilt t gives
R(t) p (R counter-clockwise in that frame), a right-handed one the same with y negated (y up).

One calibration per camera set-up, kept as a small YAML file::

    scale_px_per_mm: 5.89969
    origin_px: [195.7, 293.5]
    tilt_deg: 0.0
    handedness: left          # left (y down, the lab's) or right (y up)

or as the tracker's own string (``tracker: "Name: Calibration1, ... Scale: 5.89969
pixels/millimeter, ... Origin: 195.7, 293.5 pixels, Tilt: 0 degrees, System: Left-Handed
Coordinate, ..."``). API: :class:`Calibration` (``px_to_mm``, ``mm_to_px``,
``tracker_string``, ``from_tracker_string``, ``from_marker_distance``), :func:`load_calibration`,
:func:`save_calibration`; a calibration that cannot be read is a :class:`CalibrationError`
naming the file and the field.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
import re

import numpy as np

from mantis_sim.errors import InputError

__all__ = ['Calibration', 'CalibrationError', 'load_calibration', 'save_calibration']

HANDEDNESS = ('left', 'right')
# Millimetres per unit of the string's "pixels/<unit>". A calibration whose unit is wrong
# (the lab's "Micrometers" that are millimetres) is converted as labelled: the caller judges.
_UNIT_MM = {'millimeter': 1.0, 'millimetre': 1.0, 'mm': 1.0, 'micrometer': 1e-3,
            'micrometre': 1e-3, 'micron': 1e-3, 'um': 1e-3, 'centimeter': 10.0,
            'centimetre': 10.0, 'cm': 10.0, 'meter': 1e3, 'metre': 1e3, 'm': 1e3}
_NUMBER = r'([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)'
_YAML_FIELDS = ('scale_px_per_mm', 'origin_px', 'tilt_deg', 'handedness', 'name')


class CalibrationError(InputError):
    """A calibration that cannot be read or used, naming the file (or string) and the field."""


@dataclass(frozen=True)
class Calibration:
    """Pixels <-> the tracker's millimetres (see the module docstring for the frames)."""

    scale_px_per_mm: float
    origin_px: tuple[float, float] = (0.0, 0.0)
    tilt_deg: float = 0.0
    handedness: str = 'left'
    name: str = 'Calibration1'

    def __post_init__(self):
        _check(self, 'calibration')

    @property
    def mm_per_px(self) -> float:
        return 1.0 / self.scale_px_per_mm

    def px_to_mm(self, xy_px) -> np.ndarray:
        """(..., 2) image pixels -> (..., 2) millimetres; NaN stays NaN (a gap)."""
        p = (np.asarray(xy_px, float) - np.asarray(self.origin_px)) / self.scale_px_per_mm
        q = p @ self._turn().T
        if self.handedness == 'right':
            q = q * np.array([1.0, -1.0])
        return q

    def mm_to_px(self, xy_mm) -> np.ndarray:
        """(..., 2) millimetres -> (..., 2) image pixels (the inverse of :meth:`px_to_mm`)."""
        q = np.asarray(xy_mm, float)
        if self.handedness == 'right':
            q = q * np.array([1.0, -1.0])
        return q @ self._turn() * self.scale_px_per_mm + np.asarray(self.origin_px)

    def _turn(self) -> np.ndarray:
        t = math.radians(self.tilt_deg)
        c, s = math.cos(t), math.sin(t)
        if self.tilt_deg % 90 == 0:             # 0, 90, 180, 270 exactly: no 1e-16 residues
            c, s = round(c), round(s)
        return np.array([[c, -s], [s, c]])

    # ------------------------------------------------------------ the tracker's string
    def tracker_string(self) -> str:
        """The calibration as the tracker's ``Calibration 1:`` cell writes it."""
        ox, oy = self.origin_px
        return (f'Name: {self.name}, Type: Normal, Scale: {_exact(self.scale_px_per_mm)} '
                f'pixels/millimeter, {self.mm_per_px:.6g} millimeters/pixel, Origin: '
                f'{_exact(ox)}, {_exact(oy)} pixels, Tilt: {_exact(self.tilt_deg)} degrees, '
                f'System: {self.handedness.title()}-Handed Coordinate, '
                'Calibration Units: Millimeters')

    @classmethod
    def from_tracker_string(cls, text: str, where: str = 'calibration string') -> Calibration:
        """Parse the tracker's string (``where`` names its source in errors). Scale and origin
        are required; tilt 0 and left-handed where the string states neither."""
        text = str(text)
        scale = re.search(rf'Scale:\s*{_NUMBER}\s*pixels?\s*/\s*([A-Za-zµ]+)', text, re.I)
        per_px = re.search(rf'{_NUMBER}\s*([A-Za-zµ]+?)s?\s*/\s*pixel', text, re.I)
        if scale:
            value, unit = float(scale.group(1)), _unit_mm(scale.group(2), where)
            px_per_mm = value / unit
        elif per_px:
            value, unit = float(per_px.group(1)), _unit_mm(per_px.group(2), where)
            px_per_mm = 1.0 / (value * unit) if value else math.inf
        else:
            raise CalibrationError(f'{where}: field Scale: no "Scale: N pixels/millimeter" '
                                   'nor "N millimeters/pixel"')
        origin = re.search(rf'Origin:\s*{_NUMBER}\s*,\s*{_NUMBER}', text, re.I)
        if not origin:
            raise CalibrationError(f'{where}: field Origin: no "Origin: X, Y pixels"')
        tilt = re.search(rf'Tilt:\s*{_NUMBER}', text, re.I)
        system = re.search(r'System:\s*(\w+)', text, re.I)
        name = re.search(r'Name:\s*([^,]*)', text, re.I)
        handedness = system.group(1).lower().split('-')[0] if system else 'left'
        if handedness not in HANDEDNESS:
            raise CalibrationError(f'{where}: field System: {system.group(1)!r} is neither '
                                   'Left-Handed nor Right-Handed')
        return _built(where, scale_px_per_mm=px_per_mm,
                      origin_px=(float(origin.group(1)), float(origin.group(2))),
                      tilt_deg=float(tilt.group(1)) if tilt else 0.0, handedness=handedness,
                      name=(name.group(1).strip() if name else '') or 'Calibration1')

    @classmethod
    def from_marker_distance(cls, a_px, b_px, distance_mm: float,
                             origin_px=(0.0, 0.0), tilt_deg: float = 0.0,
                             handedness: str = 'left') -> Calibration:
        """The scale from two markers ``distance_mm`` apart, seen at ``a_px`` and ``b_px``."""
        gap_px = float(np.hypot(*(np.asarray(b_px, float) - np.asarray(a_px, float))))
        if not (math.isfinite(distance_mm) and distance_mm > 0):
            raise CalibrationError(f'marker distance {distance_mm!r} mm: not a positive length')
        if not (math.isfinite(gap_px) and gap_px > 0):
            raise CalibrationError(f'marker distance: the two markers are {gap_px} px apart')
        return _built('marker distance', scale_px_per_mm=gap_px / distance_mm,
                      origin_px=tuple(float(v) for v in origin_px), tilt_deg=float(tilt_deg),
                      handedness=handedness)

    def as_dict(self) -> dict:
        return {'scale_px_per_mm': self.scale_px_per_mm,
                'origin_px': [float(v) for v in self.origin_px],
                'tilt_deg': self.tilt_deg, 'handedness': self.handedness, 'name': self.name}


def load_calibration(path) -> Calibration:
    """A calibration YAML file (the fields, or ``tracker:`` with the tracker's string)."""
    import yaml
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as exc:
        raise CalibrationError(f'{path}: cannot read the calibration ({exc.strerror})') from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise CalibrationError(f'{path}: not a YAML calibration ({exc})') from None
    if not isinstance(data, dict):
        raise CalibrationError(f'{path}: a calibration is a YAML mapping with '
                               f'scale_px_per_mm and origin_px (found {type(data).__name__})')
    if 'tracker' in data:
        extra = sorted(set(data) - {'tracker'})
        if extra:
            raise CalibrationError(f'{path}: field {extra[0]}: give the tracker\'s string or '
                                   'the fields, not both')
        return Calibration.from_tracker_string(data['tracker'], f'{path}: tracker')
    unknown = sorted(set(data) - set(_YAML_FIELDS))
    if unknown:
        raise CalibrationError(f'{path}: field {unknown[0]}: unknown (expected '
                               f'{", ".join(_YAML_FIELDS)}, or tracker)')
    for key in ('scale_px_per_mm', 'origin_px'):
        if key not in data:
            raise CalibrationError(f'{path}: field {key}: missing')
    origin = data['origin_px']
    if not (isinstance(origin, (list, tuple)) and len(origin) == 2):
        raise CalibrationError(f'{path}: field origin_px: {origin!r} is not [x, y] pixels')
    values = {'scale_px_per_mm': data['scale_px_per_mm'], 'origin_px': tuple(origin),
              'tilt_deg': data.get('tilt_deg', 0.0),
              'handedness': data.get('handedness', 'left'),
              'name': str(data.get('name', 'Calibration1'))}
    return _built(str(path), **values)


def save_calibration(calibration: Calibration, path) -> Path:
    """Write ``calibration`` as a YAML file (read back by :func:`load_calibration`)."""
    import yaml
    path = Path(path)
    text = ('# camera calibration (mantis_sim.camera.calibration): image pixels x right, y down\n'
            f'# tracker: "{calibration.tracker_string()}"\n'
            + yaml.safe_dump(calibration.as_dict(), sort_keys=False, default_flow_style=None))
    path.write_text(text, encoding='utf-8')
    return path


# ------------------------------------------------------------------------------- internals
def _exact(value: float) -> str:
    """The shortest text that reads back as the same float ('0' for 0.0, as the tracker)."""
    text = repr(float(value))
    return text[:-2] if text.endswith('.0') else text


def _unit_mm(unit: str, where: str) -> float:
    key = unit.lower().rstrip('s')
    if key not in _UNIT_MM:
        raise CalibrationError(f'{where}: field Scale: unknown unit {unit!r}')
    return _UNIT_MM[key]


def _built(where: str, **values) -> Calibration:
    """A Calibration of ``values`` (numbers coerced), its errors naming ``where``."""
    for key in ('scale_px_per_mm', 'tilt_deg'):
        values[key] = _number(values[key], where, key)
    values['origin_px'] = tuple(_number(v, where, 'origin_px') for v in values['origin_px'])
    values['handedness'] = str(values['handedness']).strip().lower()
    try:
        return Calibration(**values)
    except CalibrationError as exc:
        raise CalibrationError(str(exc).replace('calibration:', f'{where}:', 1)) from None


def _number(value, where: str, field: str) -> float:
    if isinstance(value, bool):
        raise CalibrationError(f'{where}: field {field}: {value!r} is not a number')
    try:
        return float(value)
    except (TypeError, ValueError):
        raise CalibrationError(f'{where}: field {field}: {value!r} is not a number') from None


def _check(cal: Calibration, where: str) -> None:
    s = cal.scale_px_per_mm
    if not (isinstance(s, (int, float)) and math.isfinite(s) and s > 0):
        raise CalibrationError(f'{where}: field scale_px_per_mm: {s!r} is not a positive '
                               'number of pixels per millimetre')
    if len(cal.origin_px) != 2 or not all(isinstance(v, (int, float)) and math.isfinite(v)
                                          for v in cal.origin_px):
        raise CalibrationError(f'{where}: field origin_px: {cal.origin_px!r} is not two finite '
                               'pixel coordinates')
    if not (isinstance(cal.tilt_deg, (int, float)) and math.isfinite(cal.tilt_deg)):
        raise CalibrationError(f'{where}: field tilt_deg: {cal.tilt_deg!r} is not a finite '
                               'angle')
    if cal.handedness not in HANDEDNESS:
        raise CalibrationError(f'{where}: field handedness: {cal.handedness!r} (expected left '
                               'or right)')
