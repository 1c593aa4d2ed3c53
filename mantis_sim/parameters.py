"""Typed, validated scene parameters.

A scene is a set of sections (geometry, body, arm, ...), each a frozen dataclass whose fields carry
their unit, valid range and meaning. Units inside the physics are g, mm, ms, rad (so N, mJ, m/s);
angles in scene files are degrees where the name says `_deg`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
import math
from typing import Any, Optional

from .errors import InputError


class ParameterError(InputError):
    """A scene key or value is unknown or out of range; the message names key, value and range."""


def param(default, unit: str, doc: str, lo: Optional[float] = None, hi: Optional[float] = None,
          choices: Optional[tuple] = None, lo_open: bool = False):
    return field(default=default, metadata=dict(unit=unit, doc=doc, lo=lo, hi=hi,
                                                choices=choices, lo_open=lo_open))


@dataclass(frozen=True)
class Geometry:
    L1_mm: float = param(19.0, 'mm', 'body pivot a to arm pivot b', 1.0, 100.0)
    L2_mm: float = param(1.5, 'mm', 'arm pivot b to tendon attachment c', 0.1, 20.0)
    L3_mm: float = param(18.66, 'mm', 'arm pivot b to arm tip', 1.0, 100.0)
    L5_mm: float = param(5.0, 'mm', 'arm pivot b to inner end of the blade', 0.0, 100.0)
    d_t_mm: float = param(23.0, 'mm', 'body pivot a to tendon guide hole d (ground x-axis)',
                          1.0, 100.0)
    alpha_deg: float = param(50.63, 'deg', 'spring rest angle offset: theta1_0 = pi + alpha',
                             -180.0, 180.0)
    beta_deg: float = param(140.24, 'deg', 'angle of the tendon attachment on the arm',
                            -180.0, 180.0)
    contact_angle_deg: float = param(3.0, 'deg', 'contact (latch) angle phi_c, as recorded '
                                     'for a strike; the arm rests at it + latch_offset_deg',
                                     0.0, 15.0)
    # Where the arm actually sits on the latch differs by the day's assembly: in the tracks it
    # is 0 to 11 degrees off the body, which the recorded contact angle does not say, and the
    # days that store least have it furthest out (docs/fidelity.md, a day's own state).
    latch_offset_deg: float = param(0.0, 'deg', "the arm's latched angle minus the contact "
                                    'angle: where it sits on the latch on a given day (a day\'s '
                                    'state, mantis day-state)', -15.0, 15.0)

    @property
    def latched_angle_deg(self) -> float:
        """The arm's angle relative to the body while latched: contact angle + offset."""
        return self.contact_angle_deg + self.latch_offset_deg


@dataclass(frozen=True)
class Body:
    mass_g: float = param(0.53, 'g', 'body mass', 0.0, 100.0, lo_open=True)
    inertia_g_mm2: float = param(28.08, 'g mm^2', 'body moment of inertia about its COM',
                                 0.0, 1e5)
    com_x_mm: float = param(6.53, 'mm', 'COM offset across the body (body frame)', -100.0, 100.0)
    com_y_mm: float = param(10.98, 'mm', 'COM offset along a->b (body frame)', -100.0, 100.0)
    area_mm2: float = param(300.0, 'mm^2', 'body plate area for drag and added mass', 0.0, 1e4)
    drag_coefficient: float = param(2.0, '1', 'body plate drag coefficient (broadside)',
                                    0.0, 10.0)


@dataclass(frozen=True)
class Arm:
    mass_g: float = param(0.115, 'g', 'arm mass', 0.0, 100.0, lo_open=True)
    inertia_g_mm2: float = param(2.76, 'g mm^2', 'arm moment of inertia about its COM', 0.0, 1e5)
    com_x_mm: float = param(1.36, 'mm', 'COM offset across the arm (arm frame)', -100.0, 100.0)
    com_y_mm: float = param(3.78, 'mm', 'COM offset along the arm b->tip (arm frame)',
                            -100.0, 100.0)
    blade_area_mm2: float = param(121.0, 'mm^2', 'arm blade area (from L5 to the tip)', 0.0, 1e4)
    # The blade's section coefficients for strip theory (FluidDrag), a the angle between a
    # strip's velocity and the blade: C_D = edge_on + (broadside - edge_on) sin^2 a and
    # C_L = lift_peak sin 2a. Defaults: a flat plate at Re ~ 1e4-1e5 (Hoerner, Fluid-Dynamic
    # Drag, 1965: 1.98 broadside in two dimensions; its normal force C_N = C_D,90 sin a gives
    # C_L = (C_D,90 / 2) sin 2a), edge-on the laminar skin friction of both faces (Blasius,
    # 2 x 1.33 / sqrt(Re): 0.05 at Re 3e3, less above; the strike's chord Re is 1e4-4e4).
    # The revolving-wing values of insect flight (C_D 3.4 broadside, 0.4 edge-on, C_L 1.8 at
    # Re ~ 1e2, where a leading-edge vortex stays attached) slowed the water strike to 3.4 m/s
    # against the real robot's 4.6 (README, "Water").
    blade_drag_broadside: float = param(2.0, '1', 'blade section drag coefficient broadside',
                                        0.0, 10.0)
    blade_drag_edge_on: float = param(0.05, '1', 'blade section drag coefficient edge-on',
                                      0.0, 10.0)
    blade_lift_peak: float = param(1.0, '1', 'blade section lift coefficient at 45 deg',
                                   0.0, 10.0)


@dataclass(frozen=True)
class Spring:
    k_Nmm_per_rad: float = param(47.7, 'N mm/rad', 'torsion spring between ground and body',
                                 0.0, 1e4)


@dataclass(frozen=True)
class Hinge:
    k_Nmm_per_rad: float = param(0.71, 'N mm/rad', 'arm hinge stiffness (effect hinge_stiffness)',
                                 0.0, 1e3)
    rest_angle_deg: float = param(39.76, 'deg', 'hinge rest angle theta3h', -180.0, 180.0)
    # The real robot is loaded past overcentering with its arm still on the body (the tracks:
    # 0.4-0.5 rad of body rotation past it with the 19 mm guide, 0-0.14 rad with the 23 mm
    # one), which a frictionless pivot cannot do. Coulomb friction at the arm's pivot pin,
    # mu x pin radius x pin load, with the tendon force as the pin load: it holds the arm until
    # the tendon's opening moment exceeds lever x tension, and brakes its swing by as much.
    friction_lever_mm: float = param(0.0, 'mm', 'arm pivot friction: the most torque it holds '
                                     'is this lever (mu_static x pin radius) x the tendon force '
                                     '(effect pivot_friction)', 0.0, 5.0)
    kinetic_friction_ratio: float = param(1.0, '1', 'mu_kinetic / mu_static of the arm pivot: '
                                          'the sliding pivot brakes with this share of the '
                                          'static limit (effect pivot_friction)', 0.0, 1.0)
    # What holds the arm varies from day to day on the real robot, how hard its swing is
    # braked does not follow it (docs/fidelity.md): a braking lever of its own keeps the
    # braking where a study moves the hold.
    kinetic_friction_lever_mm: Optional[float] = param(
        None, 'mm', 'arm pivot friction while it slides: the braking torque is this lever x '
        'the tendon force; when given, kinetic_friction_ratio is not used (default: '
        'kinetic_friction_ratio x friction_lever_mm; effect pivot_friction)', 0.0, 5.0)


@dataclass(frozen=True)
class Damping:
    body_Nmm_ms_per_rad: float = param(65.3, 'N mm ms/rad', 'viscous damping on theta1',
                                       0.0, 1e4)
    arm_Nmm_ms_per_rad: float = param(4.0, 'N mm ms/rad', 'viscous damping on theta3', 0.0, 1e4)


#: The media a robot strikes in and their densities (g/mm^3): the one table a medium's name is
#: given its density from (mantis_sim.trial_conditions). Water: 750 x air, as in the authors' fits.
MEDIUM_DENSITIES_G_PER_MM3 = {'air': 1.225e-6, 'water': 750 * 1.225e-6, 'vacuum': 0.0}


@dataclass(frozen=True)
class Medium:
    name: str = param('air', '', 'medium the robot strikes in',
                      choices=tuple(MEDIUM_DENSITIES_G_PER_MM3))
    density_g_per_mm3: float = param(MEDIUM_DENSITIES_G_PER_MM3['air'], 'g/mm^3', 'fluid density '
                                     '(water: 750 x air, as in the authors\' fits)', 0.0, 0.01)
    # At least 1e-9 m/s: its square enters the drag's |v| (FluidDrag); below ~1e-162 m/s that
    # square is 0.0 and a strip at rest divided zero by zero.
    regularisation_speed_m_per_s: float = param(
        1e-4, 'm/s', 'speed below which the angle of attack is smoothed out', 1e-9, 1.0)


@dataclass(frozen=True)
class Tendon:
    model: str = param('rigid', '', 'rigid (moving constraint) or compliant (stiff spring)',
                       choices=('rigid', 'compliant'))
    stiffness_N_per_mm: float = param(50.0, 'N/mm', 'Kevlar + load cell stiffness (compliant)',
                                      0.0, 1e7, lo_open=True)
    damping_N_ms_per_mm: float = param(0.0, 'N ms/mm', 'tendon damping (compliant)', 0.0, 1e4)
    saturation_N: float = param(17.0, 'N', 'tension at which the rigid tendon yields (effect '
                                'tendon_force_saturation)', 0.0, 1e4, lo_open=True)


@dataclass(frozen=True)
class Contact:
    restitution: float = param(0.3, '1', 'coefficient of restitution on re-contact '
                               '(effect contact_restitution; otherwise 0)', 0.0, 1.0)
    latch_speed_rad_per_s: float = param(1.0, 'rad/s', 'below this rebound speed the arm '
                                         're-latches instead of bouncing', 0.0, 1e4)


@dataclass(frozen=True)
class Drive:
    pull_speed_mm_per_s: float = param(2.33, 'mm/s', 'stage pull speed (rig: 0.5-2.4)',
                                       0.0, 1000.0)
    acceleration_mm_per_s2: float = param(4.0, 'mm/s^2', 'stage acceleration ramp '
                                          '(effect stage_profile)', 0.0, 1e6, lo_open=True)
    following_time_constant_ms: float = param(0.0, 'ms', 'first-order following error of the '
                                              'stage servo (effect stage_profile)', 0.0, 1000.0)
    start_position_mm: float = param(10.0, 'mm', 'stage position at the start pose (simulated '
                                     'rig; the stage travels 0-25 mm)', 0.0, 25.0)
    travel_mm: float = param(25.0, 'mm', 'the stage\'s travel (MTS25: 25 mm): a simulated pull '
                             'ends when the stage reaches it', 0.0, 1000.0, lo_open=True)


@dataclass(frozen=True)
class Initial:
    theta1_rad: float = param(2.4812, 'rad', 'start body angle', -2 * math.pi, 2 * math.pi)
    theta3_deg: Optional[float] = param(None, 'deg', 'start arm angle (default: the latched '
                                        'angle, contact + latch offset)', 0.0, 180.0)


@dataclass(frozen=True)
class LoadCell:
    capacity_N: float = param(111.0, 'N', 'load-cell capacity (Futek LSB302, 25 lb)', 1.0, 1e4)
    bandwidth_hz: float = param(1000.0, 'Hz', 'amplifier bandwidth (effect loadcell_dynamics)',
                                1.0, 1e6)
    noise_N: float = param(0.01, 'N', 'rms noise (effect loadcell_dynamics)', 0.0, 10.0)
    adc_bits: int = param(16, 'bit', 'ADC resolution (effect loadcell_dynamics)', 8, 24)
    adc_range_V: float = param(10.0, 'V', 'ADC input range +/- (effect loadcell_dynamics)',
                               0.1, 10.0)
    newtons_per_volt: float = param(11.12, 'N/V', 'amplifier calibration', 0.0, 1e4,
                                    lo_open=True)


@dataclass(frozen=True)
class Camera:
    frame_rate_hz: float = param(19000.0, 'Hz', 'camera frame rate', 1.0, 37000.0)
    pixel_mm: float = param(0.1695, 'mm', 'pixel size in the marker plane (effect '
                            'camera_sampling)', 0.0, 10.0, lo_open=True)
    # The tracker follows markers to sub-pixel precision: every real export's positions are
    # multiples of 0.1 pixel (checked on all seven shared exports).
    tracker_resolution_px: float = param(0.1, 'px', 'step of the tracked positions (effect '
                                         'camera_sampling)', 0.0, 10.0, lo_open=True)
    # Still markers on the real exports jitter by 0.00-0.06 px rms (second differences of the
    # first 3,000 frames of seven exports), 0.03 px typical.
    tracking_noise_px: float = param(0.03, 'px', 'rms tracking noise before the tracker\'s '
                                     'rounding (effect camera_sampling)', 0.0, 10.0)


@dataclass(frozen=True)
class Integration:
    # The compiled Radau (mantis_sim.fast) at 1e-7 is within ~2e-9 of the converged peak tip
    # speed on the rigid-tendon scenes at ~5 ms a strike (docs/accuracy_air_23mm.md);
    # scipy's solvers stay, Radau at rtol 1e-10 as the judge of the fast path.
    solver: str = param('fast', '', 'integrator: fast (the compiled Radau IIA of '
                        'mantis_sim.fast), or one of scipy\'s', choices=(
        'fast', 'RK45', 'RK23', 'DOP853', 'Radau', 'BDF', 'LSODA'))
    rtol: float = param(1e-7, '1', 'relative tolerance', 1e-13, 1e-2)
    atol_scale: float = param(1e-3, '1', 'absolute tolerance = rtol x this x state scale',
                              1e-9, 1.0, lo_open=True)
    t_end_s: Optional[float] = param(None, 's', 'stop here if no strike by then (default: run '
                                     'until the strike, or until the stage\'s travel is used '
                                     'up)', 0.0, 1e7, lo_open=True)
    post_peak_ms: float = param(0.0, 'ms', 'keep simulating this long after peak tip speed',
                                0.0, 1e4)
    baumgarte_per_ms: float = param(0.05, '1/ms', 'rigid-constraint drift correction rate',
                                    0.0, 100.0)
    # mantis_sim.stiff_tendon: the ringing of a very stiff tendon need not be resolved
    rigid_tendon_below: float = param(1e-4, '1', 'the fast path solves a compliant tendon as '
                                      'rigid when its estimated effect on the strike is below '
                                      'this (0: never)', 0.0, 0.1)


SECTIONS: dict[str, type] = {
    'geometry': Geometry, 'body': Body, 'arm': Arm, 'spring': Spring, 'hinge': Hinge,
    'damping': Damping, 'medium': Medium, 'tendon': Tendon, 'contact': Contact,
    'drive': Drive, 'initial': Initial, 'loadcell': LoadCell, 'camera': Camera,
    'integration': Integration,
}


def _check_value(key: str, meta: dict, annotation: str, value: Any) -> Any:
    if meta['choices'] is not None:
        if value not in meta['choices']:
            raise ParameterError(f'{key} = {value!r} is not valid; valid values: '
                                 f'{", ".join(map(str, meta["choices"]))}')
        return value
    if value is None and 'Optional' in annotation:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f'{key} = {value!r} is not a number '
                             f'(valid range {_range_text(meta)})')
    try:
        if annotation == 'int' and float(value) != int(value):
            raise ParameterError(f'{key} = {value!r} must be a whole number')
        value = int(value) if annotation == 'int' else float(value)
    except OverflowError:          # an integer too big for a float (a 400-digit number)
        raise ParameterError(f'{key} = {_short(value)} is out of range; valid range '
                             f'{_range_text(meta)}') from None
    lo, hi = meta['lo'], meta['hi']
    too_low = lo is not None and (value <= lo if meta['lo_open'] else value < lo)
    if not math.isfinite(value) or too_low or (hi is not None and value > hi):
        raise ParameterError(f'{key} = {value!r} is out of range; valid range {_range_text(meta)}')
    return value


def _short(value, limit: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= limit else f'{text[:limit]}... ({len(text)} characters)'


def _range_text(meta: dict) -> str:
    left = '(' if meta['lo_open'] else '['
    unit = f' {meta["unit"]}' if meta['unit'] else ''
    return f'{left}{meta["lo"]:g}, {meta["hi"]:g}]{unit}'


def build_section(name: str, data: Any, base=None):
    """Make section `name` from a mapping, over `base` (or the defaults); validate every key."""
    cls = SECTIONS[name]
    if not isinstance(data, dict):
        raise ParameterError(f'{name} must be a mapping of keys to values, got {data!r}')
    known = {f.name: f for f in fields(cls)}
    values = {}
    for key, value in data.items():
        if key not in known:
            raise ParameterError(f'unknown key {name}.{key} (= {value!r}); valid keys in '
                                 f'{name}: {", ".join(known)}')
        values[key] = _check_value(f'{name}.{key}', known[key].metadata, known[key].type, value)
    return replace(base if base is not None else cls(), **values)


def describe(section_name: str) -> list[tuple[str, Any, str, str]]:
    """(key, default, unit, doc) rows for documentation and `mantis scenes --params`."""
    cls = SECTIONS[section_name]
    return [(f'{section_name}.{f.name}', f.default, f.metadata['unit'], f.metadata['doc'])
            for f in fields(cls)]
