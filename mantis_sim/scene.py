"""Scenes: the rig's geometry, parameters, medium, drive and the effects to simulate, from YAML."""
from __future__ import annotations

from collections.abc import Iterable
import copy
from dataclasses import dataclass, field, replace
from importlib import resources
import os
from pathlib import Path
from typing import Optional

import yaml

from .errors import InputError
from .parameters import (
    SECTIONS,
    Arm,
    Body,
    Camera,
    Contact,
    Damping,
    Drive,
    Geometry,
    Hinge,
    Initial,
    Integration,
    LoadCell,
    Medium,
    ParameterError,
    Spring,
    Tendon,
    build_section,
)
from .spread import Spread

# Each effect is a term of the model or of a sensor, assembled only when a scene enables it.
EFFECTS = {
    'gravity': 'gravity on both bodies (tiny: ~0.05 mJ against ~100 mJ of spring energy)',
    'joint_damping': 'viscous damping on theta1 and theta3',
    'hinge_stiffness': 'weak arm hinge spring pulling theta3 towards theta3h',
    'fluid_drag': 'quadratic drag on the body; quasi-steady lift and drag on the arm blade',
    'added_mass': 'entrained fluid inertia of body and arm blade (configuration dependent)',
    'tendon_slack': 'the tendon cannot push: it goes slack when its tension would turn negative',
    'contact_restitution': 'the arm rebounds on re-contact (otherwise re-contact is plastic)',
    'pivot_friction': 'Coulomb friction at the arm pivot, hinge.friction_lever_mm x the tendon '
                      'force: holds the arm on the body past overcentering, brakes its swing '
                      '(x hinge.kinetic_friction_ratio) and stops it where it cannot overcome '
                      'it (stick-slip, by events)',
    'stage_profile': 'stage acceleration ramp and servo following error',
    'loadcell_dynamics': 'amplifier bandwidth, noise and ADC quantisation of the force signal',
    'camera_sampling': 'pixel quantisation of the tracked markers',
    'published_arm_air_load': 'the arm blade\'s air load in the authors\' published form (off-axis '
                              'centre of pressure, C_D 0.4 along the blade to 3.4 across it, '
                              'one-sided lift), '
                              'replacing fluid_drag\'s blade term: to reproduce their simulation',
    'published_added_mass': 'entrained fluid in the authors\' published form (elliptic plates at '
                            'the centres of mass, lengths scaled by 1.8), instead of added_mass: '
                            'to reproduce their simulation',
    'tendon_force_saturation': 'the rigid tendon yields at tendon.saturation_N: it stretches at '
                               'that tension and locks again when it has shortened back',
}


class SceneError(InputError):
    """A scene cannot be found or parsed; the message names the file and the problem."""


@dataclass(frozen=True)
class Scene:
    name: str
    description: str
    effects: frozenset
    geometry: Geometry = Geometry()
    body: Body = Body()
    arm: Arm = Arm()
    spring: Spring = Spring()
    hinge: Hinge = Hinge()
    damping: Damping = Damping()
    medium: Medium = Medium()
    tendon: Tendon = Tendon()
    contact: Contact = Contact()
    drive: Drive = Drive()
    initial: Initial = Initial()
    loadcell: LoadCell = LoadCell()
    camera: Camera = Camera()
    integration: Integration = Integration()
    # Where an identified scene's values come from (`mantis identify`): kept, never simulated.
    provenance: Optional[dict] = field(default=None, compare=False, hash=False)
    # How robots of this design scatter (`mantis identify --spread`; mantis_sim.spread): drawn
    # by `--spread N`, never by a single simulation.
    spread: Optional[Spread] = field(default=None, compare=False, hash=False)

    def has(self, effect: str) -> bool:
        return effect in self.effects

    def with_overrides(self, assignments: Iterable[str]) -> Scene:
        """Apply `section.key=value` strings (values parsed as YAML scalars), all at once: keys
        that constrain each other (contact angle and latch offset) are checked together."""
        values = {}
        for text in assignments:
            key, sep, raw = text.partition('=')
            if not sep:
                raise ParameterError(f'override {text!r} is not of the form section.key=value')
            values[key.strip()] = _parse_scalar(raw)
        return self.with_values(values) if values else self

    def with_values(self, values: dict) -> Scene:
        """Apply {'section.key': value} (or 'effects': [...]) and re-validate."""
        scene = self
        for key, value in values.items():
            if key == 'effects':
                scene = replace(scene, effects=_effects(value, scene.name))
                continue
            section, _, name = key.partition('.')
            if section not in SECTIONS or not name:
                raise ParameterError(f'unknown key {key!r} (= {value!r}); keys are section.name '
                                     f'with section one of: {", ".join(SECTIONS)}, or effects')
            updated = build_section(section, {name: value}, getattr(scene, section))
            scene = replace(scene, **{section: updated})
        _check_consistency(scene)
        return scene


def _parse_scalar(raw: str):
    """A command-line value as YAML, but '1e-6' is a number (YAML 1.1 wants '1.0e-6')."""
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        return raw
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _effects(value, where: str) -> frozenset:
    if not isinstance(value, (list, tuple)):
        raise ParameterError(f'{where}: effects = {value!r} is not a list; valid effects: '
                             f'{", ".join(EFFECTS)}')
    unknown = [e for e in value if e not in EFFECTS]
    if unknown:
        raise ParameterError(f'{where}: effects = {list(value)!r}: unknown effect(s) '
                             f'{", ".join(map(str, unknown))}; valid effects: '
                             f'{", ".join(EFFECTS)}')
    return frozenset(value)


def _check_consistency(scene: Scene) -> None:
    g = scene.geometry
    if g.L5_mm >= g.L3_mm:
        raise ParameterError(f'geometry.L5_mm = {g.L5_mm} must be below geometry.L3_mm = '
                             f'{g.L3_mm} (the blade lies between L5 and the tip)')
    needs_fluid = scene.effects & {'fluid_drag', 'added_mass', 'published_arm_air_load',
                                   'published_added_mass'}
    if {'added_mass', 'published_added_mass'} <= scene.effects:
        raise ParameterError('effects added_mass and published_added_mass are two forms of the '
                             'same fluid inertia: enable one')
    if needs_fluid and scene.medium.density_g_per_mm3 <= 0:
        raise ParameterError(f'effects {", ".join(sorted(needs_fluid))} need '
                             f'medium.density_g_per_mm3 > 0 (got 0)')
    if scene.drive.start_position_mm >= scene.drive.travel_mm:
        raise ParameterError(f'drive.start_position_mm = {scene.drive.start_position_mm} leaves '
                             f'no travel: it must be below drive.travel_mm = '
                             f'{scene.drive.travel_mm}')
    hinge = scene.hinge
    if (hinge.kinetic_friction_lever_mm is not None
            and hinge.kinetic_friction_lever_mm > hinge.friction_lever_mm):
        raise ParameterError(f'hinge.kinetic_friction_lever_mm = {hinge.kinetic_friction_lever_mm}'
                             f' exceeds hinge.friction_lever_mm = {hinge.friction_lever_mm}: a '
                             f'sliding pivot cannot brake more than it can hold')
    if not 0.0 <= g.latched_angle_deg <= 15.0:
        raise ParameterError(f'geometry.contact_angle_deg = {g.contact_angle_deg} with '
                             f'geometry.latch_offset_deg = {g.latch_offset_deg} puts the latched '
                             f'arm at {g.latched_angle_deg:g} degrees: it must lie in [0, 15]')
    theta3 = scene.initial.theta3_deg
    if theta3 is not None and theta3 < g.latched_angle_deg:
        raise ParameterError(f'initial.theta3_deg = {theta3} is below the latched arm: it must '
                             f'be >= geometry.contact_angle_deg + latch_offset_deg = '
                             f'{g.latched_angle_deg:g}')


#: What a scene file must state; every other section has a documented default.
REQUIRED_FILE_KEYS = ('name', 'effects', 'geometry', 'medium', 'tendon', 'drive')


def scene_from_dict(data, name: str = '<scene>') -> Scene:
    if not isinstance(data, dict):
        raise SceneError(f'{name}: a scene must be a YAML mapping, got {type(data).__name__}')
    data = dict(data)
    scene_name = data.pop('name', name)
    description = data.pop('description', '')
    provenance = data.pop('provenance', None)
    if provenance is not None and not isinstance(provenance, dict):
        raise SceneError(f'{scene_name}: provenance must be a mapping, got '
                         f'{type(provenance).__name__}')
    spread = data.pop('spread', None)
    if spread is not None:
        spread = Spread.from_mapping(spread, f'{scene_name}')
    effects = _effects(data.pop('effects', []), scene_name)
    sections = {}
    for key, value in data.items():
        if key not in SECTIONS:
            raise ParameterError(f'{scene_name}: unknown key {key!r} (= {value!r}); valid '
                                 f'keys: name, description, effects, provenance, spread, '
                                 f'{", ".join(SECTIONS)}')
        sections[key] = build_section(key, value or {})
    scene = Scene(name=str(scene_name), description=str(description), effects=effects,
                  provenance=provenance, spread=spread, **sections)
    _check_consistency(scene)
    return scene


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """' at line L, column C: what is wrong (while parsing what, where)', on one line."""
    mark, problem = getattr(exc, 'problem_mark', None), getattr(exc, 'problem', None)
    if mark is None or problem is None:
        return ': ' + ' '.join(str(exc).split())
    text = f' at line {mark.line + 1}, column {mark.column + 1}: {problem}'
    context, context_mark = getattr(exc, 'context', None), getattr(exc, 'context_mark', None)
    if context:
        text += f' ({context}'
        if context_mark is not None:
            text += f' at line {context_mark.line + 1}, column {context_mark.column + 1}'
        text += ')'
    return text


#: parsed scene files: (path, mtime_ns, size) -> the YAML's data. A simulated trial reads its
#: scene several times in one process (the command line, the world, the device nodes), and
#: PyYAML's pure-Python parser takes some 25 ms a time for air_23mm.yaml.
_PARSED: dict = {}
_PARSED_KEPT = 32           # a study reads many scenes: the latest few are kept


def _parse_yaml_file(path: Path):
    """yaml.safe_load of the file's text, parsed once per version of the file (its path,
    modification time and size); each caller gets a deep copy of its own to change."""
    try:
        stat = os.stat(path)
        key = (str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size)
    except OSError:             # read_text says why
        key = None
    if key is not None and key in _PARSED:
        return copy.deepcopy(_PARSED[key])
    data = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
    if key is not None:
        if len(_PARSED) >= _PARSED_KEPT:
            _PARSED.clear()
        _PARSED[key] = copy.deepcopy(data)
    return data


def load_scene_file(path: Path) -> Scene:
    try:
        data = _parse_yaml_file(path)
    except UnicodeDecodeError as exc:
        raise SceneError(f'{path}: not UTF-8 text (byte {exc.start}: '
                         f'{exc.object[exc.start:exc.start + 1]!r})') from None
    except yaml.YAMLError as exc:
        raise SceneError(f'{path}: not valid YAML{_yaml_problem(exc)}') from None
    except OSError as exc:
        raise SceneError(f'{path}: cannot read: {exc.strerror}') from None
    try:
        scene = scene_from_dict(data, Path(path).stem)
    except ParameterError as exc:
        raise ParameterError(f'{path}: {exc}') from None
    missing = [key for key in REQUIRED_FILE_KEYS if key not in data]
    if missing:
        raise SceneError(
            f'{path}: missing required key(s) {", ".join(missing)}: a scene file states '
            f'{", ".join(REQUIRED_FILE_KEYS)} (effects may be []); the other sections '
            f'({", ".join(k for k in SECTIONS if k not in REQUIRED_FILE_KEYS)}) default to the '
            f'published robot. A file cut short must not run on defaults.')
    return scene


def scene_dirs() -> list[Path]:
    """Where scenes are looked up: $MANTIS_SCENE_PATH, then the scenes shipped with mantis_sim
    (package data, `mantis_sim/scenes/`)."""
    dirs = [Path(p) for p in os.environ.get('MANTIS_SCENE_PATH', '').split(os.pathsep) if p]
    dirs.append(Path(str(resources.files(__package__) / 'scenes')))
    return [d for d in dirs if d.is_dir()]


def available_scenes() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for folder in reversed(scene_dirs()):
        for path in sorted(folder.glob('*.yaml')):
            found[path.stem] = path
    return dict(sorted(found.items()))


def load_scene(name_or_path: str, overrides: Optional[Iterable[str]] = None) -> Scene:
    """A scene by name (see `mantis scenes`) or by path to a YAML file, with overrides applied."""
    path = Path(name_or_path)
    if not (path.suffix in ('.yaml', '.yml') and path.exists()):
        scenes = available_scenes()
        if name_or_path not in scenes:
            raise SceneError(f'unknown scene {name_or_path!r}; available scenes: '
                             f'{", ".join(scenes) or "(none found)"}')
        path = scenes[name_or_path]
    return load_scene_file(path).with_overrides(overrides or [])
