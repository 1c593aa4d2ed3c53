"""A rig trial's conditions, defined once: their keys, units and ranges, and the scene keys
that state them (no ROS).

The rig records four conditions with every trial (the supervisor's parameters, the bag's
``trial_conditions``); each is one scene key:

=====================  =========================================================================
condition              scene
=====================  =========================================================================
``pull_speed_mm_s``    ``drive.pull_speed_mm_per_s``
``d_t_mm``             ``geometry.d_t_mm``
``contact_angle_deg``  ``geometry.contact_angle_deg``: the recorded contact angle (the shim); the
                       arm sits on the latch at it + ``geometry.latch_offset_deg``, which a
                       scene's spread draws (mantis_sim.robots), not the condition
``medium``             ``medium.name``, and the density of that medium from
                       ``MEDIUM_DENSITIES_G_PER_MM3`` (a scene already in that medium keeps its
                       own density: the condition does not say it)
=====================  =========================================================================

``CONDITIONS`` says each one's unit, the rig's default and the range a trial may record (the
supervisor's parameters, in the rig's contract), and the narrower range the simulated world can
build its robot at (its parameters). Everything that names the conditions takes them from here:
the rig's contract and its trial record, a study's plan, the launch file and `mantis bringup`
(a scene's conditions: ``conditions_of_scene``).

``scene_for_conditions`` applies whichever of them are given and refuses, with ParameterError
naming the condition and why, one the scene cannot take (vacuum for a scene whose effects need
a fluid, a contact angle that puts the latched arm outside [0, 15] degrees, a value out of its
scene key's range). ``conditions_of_scene`` is its inverse. The simulated rig builds each
latching's robot through it (the rig's simulated world node), and a study forecasts a trial at
its conditions with it.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math

from .parameters import MEDIUM_DENSITIES_G_PER_MM3, ParameterError
from .scene import Scene


@dataclass(frozen=True)
class Condition:
    """One trial condition: its key, unit ('' for none), what it is, the scene key that states
    it, the rig's default, the range a trial may record (inclusive; ``high`` None: up to the
    rig's own limit, the stage's speed ceiling) or its choices, and the range the simulated
    world can build its robot at."""

    key: str
    unit: str
    doc: str
    scene_key: str
    default: object
    range: tuple | None = None
    choices: tuple | None = None
    simulated_range: tuple | None = None


#: the media a robot can strike in
MEDIA = tuple(MEDIUM_DENSITIES_G_PER_MM3)
#: the conditions a rig trial records that the scene simulates, in the order of the table above
CONDITIONS = (
    Condition('pull_speed_mm_s', 'mm/s', 'stage pull speed during the trial',
              'drive.pull_speed_mm_per_s', 2.33, range=(0.05, None)),
    Condition('d_t_mm', 'mm', 'tendon guide distance from the body pivot', 'geometry.d_t_mm',
              23.0, range=(1.0, 100.0), simulated_range=(1.0, 100.0)),
    Condition('contact_angle_deg', 'deg', 'contact angle, as recorded (the shim)',
              'geometry.contact_angle_deg', 3.0, range=(-45.0, 45.0),
              simulated_range=(0.0, 15.0)),
    Condition('medium', '', 'medium around the robot', 'medium.name', 'air', choices=MEDIA),
)
CONDITION_BY_KEY = {c.key: c for c in CONDITIONS}
CONDITION_KEYS = tuple(CONDITION_BY_KEY)
#: condition -> the scene key it sets (medium also sets medium.density_g_per_mm3)
SCENE_KEYS = {c.key: c.scene_key for c in CONDITIONS}
_FLUID_EFFECTS = ('fluid_drag', 'added_mass', 'published_arm_air_load', 'published_added_mass')


def conditions_of_scene(scene: Scene) -> dict:
    """The trial conditions a scene simulates: {condition: value} for every CONDITION_KEYS
    (the contact angle as recorded, not where the arm sits: that adds the latch offset)."""
    return {key: getattr(getattr(scene, section), name) for key, (section, _, name) in
            ((key, scene_key.partition('.')) for key, scene_key in SCENE_KEYS.items())}


def scene_for_conditions(scene: Scene, conditions: Mapping) -> Scene:
    """``scene`` at a trial's conditions: each of CONDITION_KEYS that ``conditions`` gives (not
    None) sets its scene key; other keys (a trial record's force ceiling, note, ...) are not the
    scene's and are left alone. Numbers may come as text (a bag's trial_conditions record).
    ParameterError (an InputError) names the condition that cannot be applied, and why."""
    for key in CONDITION_KEYS:
        value = conditions.get(key)
        if value is None:
            continue
        values = _medium(scene, value) if key == 'medium' \
            else {SCENE_KEYS[key]: _number(key, value)}
        try:
            scene = scene.with_values(values) if values else scene
        except ParameterError as exc:
            raise ParameterError(f'{key} = {value}: scene {scene.name} cannot be simulated '
                                 f'at it: {exc}') from None
    return scene


def _number(key: str, value) -> float:
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ParameterError(f'{key} = {value!r} is not a number') from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise ParameterError(f'{key} = {value!r} is not a finite number')
    return float(value)


def _medium(scene: Scene, name) -> dict:
    if name not in MEDIUM_DENSITIES_G_PER_MM3:
        raise ParameterError(f'medium = {name!r} is not one of '
                             f'{", ".join(MEDIUM_DENSITIES_G_PER_MM3)}')
    if name == scene.medium.name:
        return {}                       # the scene's own density stands
    density = MEDIUM_DENSITIES_G_PER_MM3[name]
    fluid = sorted(set(_FLUID_EFFECTS) & scene.effects)
    if density <= 0.0 and fluid:
        raise ParameterError(f'medium = {name}: scene {scene.name} simulates the fluid around '
                             f'the robot (effects {", ".join(fluid)}), which a {name} does not '
                             f'have')
    return {'medium.name': name, 'medium.density_g_per_mm3': density}


__all__ = ['CONDITIONS', 'CONDITION_BY_KEY', 'CONDITION_KEYS', 'Condition', 'MEDIA', 'SCENE_KEYS',
           'conditions_of_scene', 'scene_for_conditions']
