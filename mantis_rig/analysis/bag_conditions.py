"""Analysis parameters from what a trial bag says about its trial (``trial_conditions``).

A bag recorded by the supervisor names the scene it was run with (simulated rig) and the
conditions set for the trial: the tendon guide distance ``d_t_mm`` and the contact angle
``contact_angle_deg`` (the shim, measured on the rig). The scene gives the mechanism's
geometry, spring, inertia and the camera's view; the conditions, which are what the trial was
run with, override the scene's d_t and contact angle. A bag without them (an imported tracking
file) keeps the physics.md reference values of AnalysisParams. A bag naming a scene that
cannot be loaded here is refused (InputError), unless the user gives d_t and the contact
angle: then the reference values are used, and the analysis's parameter notes say so.
"""
from __future__ import annotations

from dataclasses import replace
import math

from mantis_rig.analysis.energy import InertiaParams
from mantis_rig.analysis.pipeline import AnalysisParams
from mantis_sim.errors import InputError

#: Trial conditions a tracking file does not carry, given on the command line (the rig's
#: bags carry them in ``trial_conditions``): trial condition -> option. Both given is what it
#: takes to analyse a bag whose scene cannot be loaded.
CONDITION_OPTIONS = {'d_t_mm': '--d-t-mm', 'contact_angle_deg': '--contact-angle-deg'}


def _gives_geometry(given: dict | None) -> bool:
    return all(_number(given or {}, key) is not None for key in CONDITION_OPTIONS)


def _number(conditions: dict, key: str) -> float | None:
    try:
        value = float(conditions[key])
    except (KeyError, TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def _check_ranges(values: dict, source: str) -> None:
    """The conditions the analysis uses, against the ranges the command line and the
    supervisor enforce (one source: trial.conditions); ConditionError names the value."""
    from mantis_rig.trial.supervisor_settings import ConditionError, check_value
    for key in CONDITION_OPTIONS:
        raw = values.get(key)
        if raw is None or raw == '':
            continue
        value = _number(values, key)
        if value is None:
            raise ConditionError(f'{source}: {key} = {raw!r} is not a finite number')
        try:
            check_value(key, value)
        except ConditionError as exc:
            raise ConditionError(f'{source}: {exc}') from None


def scene_of(conditions: dict):
    """The mantis_sim scene the trial names, or None if it names none. A scene that cannot be
    loaded (unknown here, or broken) is the InputError that says why: analysing the trial
    with another geometry, spring and inertia than its own would give wrong numbers."""
    name = str(conditions.get('scene') or '')
    if not name:
        return None
    from mantis_sim.scene import load_scene
    return load_scene(name)


def params_for_trial(conditions: dict, params: AnalysisParams | None = None,
                     given: dict | None = None) -> tuple[AnalysisParams, list[str]]:
    """(parameters, what was taken from where) for a trial with these conditions.

    ``given``: d_t_mm and contact_angle_deg stated by the user (a tracking file carries no
    trial conditions; the authors, too, measure each trial's contact angle apart from its
    tracks); they override the bag's.
    """
    params = params or AnalysisParams()
    notes = []
    try:
        scene = scene_of(conditions)
    except InputError as exc:
        if not _gives_geometry(given):
            raise InputError(
                f'its trial conditions name scene {conditions.get("scene")!r}, which cannot '
                f'be loaded here ({exc}); its geometry, spring and inertia are unknown: give '
                f'{" and ".join(CONDITION_OPTIONS.values())} to analyse it with physics.md\'s '
                f'reference values and these') from exc
        scene = None
        notes.append(f'scene {conditions.get("scene")!r} could not be loaded ({exc}): '
                     f'assumed the physics.md reference geometry, spring and inertia, '
                     f'with the given d_t and contact angle')
    if scene is not None:
        g = scene.geometry
        params = replace(
            params, L3_mm=g.L3_mm, L2_mm=g.L2_mm, beta_rad=math.radians(g.beta_deg),
            d_t_mm=g.d_t_mm, tendon_L1_mm=g.L1_mm,
            theta1_rest_rad=math.pi + math.radians(g.alpha_deg),
            k_s_Nmm_per_rad=scene.spring.k_Nmm_per_rad,
            contact_angle_rad=math.radians(g.latched_angle_deg),     # where the arm rests
            # The simulated camera looks at the mechanism's frame with image y flipped: its
            # x axis runs from the body pivot towards the tendon guide.
            guide_direction_cam_rad=0.0,
            inertia=InertiaParams(
                m1_g=scene.body.mass_g, I1_gmm2=scene.body.inertia_g_mm2,
                com1_mm=(scene.body.com_x_mm, scene.body.com_y_mm),
                m2_g=scene.arm.mass_g, I2_gmm2=scene.arm.inertia_g_mm2,
                com2_mm=(scene.arm.com_x_mm, scene.arm.com_y_mm)))
        notes.append(f'geometry, spring and inertia of scene {scene.name!r}')
    for source, values in (('trial conditions', conditions), ('given', given or {})):
        _check_ranges(values, source)
        d_t = _number(values, 'd_t_mm')
        if d_t is not None:
            params = replace(params, d_t_mm=d_t)
            notes.append(f'd_t = {d_t:g} mm ({source})')
        contact = _number(values, 'contact_angle_deg')
        if contact is not None:
            params = replace(params, contact_angle_rad=math.radians(contact))
            notes.append(f'contact angle {contact:g} deg ({source})')
    return params, notes
