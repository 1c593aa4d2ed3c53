"""mantis_sim.trial_conditions: a rig trial's conditions and the scene that simulates them, one way
and back; the refusals name the condition and why. And the session's robots drawn about the
scene at a trial's conditions (mantis_sim.robots)."""
import pytest

from mantis_rig.contract import SUPERVISOR_PARAMETERS, WORLD_CONDITIONS
from mantis_rig.trial.supervisor_settings import TrialConditions
from mantis_sim.errors import InputError
from mantis_sim.parameters import MEDIUM_DENSITIES_G_PER_MM3, Medium, ParameterError
from mantis_sim.robots import SessionRobots
from mantis_sim.scene import load_scene
from mantis_sim.trial_conditions import CONDITION_KEYS, conditions_of_scene, scene_for_conditions

RIG = 'air_23mm_rig'


@pytest.fixture(scope='module')
def rig():
    return load_scene(RIG)


def test_each_condition_sets_its_scene_key(rig):
    scene = scene_for_conditions(rig, {'pull_speed_mm_s': 1.2, 'd_t_mm': 19.0,
                                       'contact_angle_deg': 5.5, 'medium': 'water'})
    assert scene.drive.pull_speed_mm_per_s == 1.2
    assert scene.geometry.d_t_mm == 19.0
    # the recorded contact angle: where the arm sits is it + the latch offset, which stays
    assert scene.geometry.contact_angle_deg == 5.5
    assert scene.geometry.latch_offset_deg == rig.geometry.latch_offset_deg
    assert scene.geometry.latched_angle_deg == 5.5 + rig.geometry.latch_offset_deg
    assert scene.medium.name == 'water'
    assert scene.medium.density_g_per_mm3 == MEDIUM_DENSITIES_G_PER_MM3['water']
    # nothing else moved
    assert scene.with_values({'drive.pull_speed_mm_per_s': 2.33, 'geometry.d_t_mm': 23.0,
                              'geometry.contact_angle_deg': 3.0, 'medium.name': 'air',
                              'medium.density_g_per_mm3': 1.225e-6}) == rig


def test_one_table_of_media_the_scenes_agree_with():
    assert MEDIUM_DENSITIES_G_PER_MM3 == {'air': 1.225e-6, 'water': 0.00091875, 'vacuum': 0.0}
    assert Medium().density_g_per_mm3 == MEDIUM_DENSITIES_G_PER_MM3['air']
    for name in ('water_23mm', 'reference_water_23mm', 'air_23mm', 'reference_air_23mm'):
        medium = load_scene(name).medium
        assert medium.density_g_per_mm3 == MEDIUM_DENSITIES_G_PER_MM3[medium.name], name
    vacuum = scene_for_conditions(load_scene('air_23mm_rig', ['effects=[gravity]']),
                                  {'medium': 'vacuum'})
    assert vacuum.medium.density_g_per_mm3 == 0.0


def test_only_the_conditions_given_apply_and_text_is_read_as_a_bag_records_it(rig):
    assert scene_for_conditions(rig, {}) is rig
    assert scene_for_conditions(rig, {'d_t_mm': None}) is rig
    # a bag's trial_conditions record: every parameter, as text; the scene takes its four
    record = TrialConditions(d_t_mm=25.0, contact_angle_deg=4.0, pull_speed_mm_s=1.0,
                             force_ceiling_n=12.0).metadata()
    scene = scene_for_conditions(rig, record)
    assert conditions_of_scene(scene) == {'pull_speed_mm_s': 1.0, 'd_t_mm': 25.0,
                                          'contact_angle_deg': 4.0, 'medium': 'air'}


def test_the_round_trip(rig):
    for name in ('air_23mm_rig', 'air_19mm', 'water_23mm', 'reference_water_23mm'):
        scene = load_scene(name)
        conditions = conditions_of_scene(scene)
        assert tuple(conditions) == CONDITION_KEYS
        assert scene_for_conditions(scene, conditions) == scene, name
    wanted = {'pull_speed_mm_s': 0.8, 'd_t_mm': 21.0, 'contact_angle_deg': 7.0,
              'medium': 'water'}
    assert conditions_of_scene(scene_for_conditions(rig, wanted)) == wanted
    # a scene in its medium keeps its own density: the condition does not state one
    thick = rig.with_values({'medium.density_g_per_mm3': 2e-6})
    assert scene_for_conditions(thick, conditions_of_scene(thick)) == thick


def test_the_conditions_are_the_supervisors_and_the_worlds():
    supervisor = {spec.name for spec in SUPERVISOR_PARAMETERS}
    assert set(CONDITION_KEYS) <= supervisor
    # the world builds its robot from all but the pull speed, which the stage commands
    assert {spec.name for spec in WORLD_CONDITIONS} == set(CONDITION_KEYS) - {'pull_speed_mm_s'}


@pytest.mark.parametrize('conditions, message', [
    ({'medium': 'vacuum'}, 'medium = vacuum: scene air_23mm_rig simulates the fluid around the '
                           'robot (effects fluid_drag), which a vacuum does not have'),
    ({'contact_angle_deg': 20.0}, 'contact_angle_deg = 20.0: scene air_23mm_rig cannot be '
                                  'simulated at it: geometry.contact_angle_deg = 20.0 is out '
                                  'of range; valid range [0, 15] deg'),
    ({'d_t_mm': 0.5}, 'd_t_mm = 0.5: scene air_23mm_rig cannot be simulated at it: '
                      'geometry.d_t_mm = 0.5 is out of range'),
    ({'pull_speed_mm_s': 'fast'}, "pull_speed_mm_s = 'fast' is not a number"),
    ({'d_t_mm': float('nan')}, 'd_t_mm = nan is not a finite number'),
    ({'medium': 'honey'}, "medium = 'honey' is not one of air, water, vacuum"),
])
def test_conditions_a_scene_cannot_take_are_refused_naming_the_condition_and_why(
        rig, conditions, message):
    with pytest.raises(ParameterError) as refused:
        scene_for_conditions(rig, conditions)
    assert str(refused.value).startswith(message)
    assert isinstance(refused.value, InputError)


def test_a_contact_angle_that_puts_the_latched_arm_off_the_latch_is_refused(rig):
    seated = rig.with_values({'geometry.latch_offset_deg': 5.0})
    assert scene_for_conditions(seated, {'contact_angle_deg': 10.0}).geometry \
        .latched_angle_deg == 15.0
    with pytest.raises(ParameterError, match=r'contact_angle_deg = 12: scene air_23mm_rig '
                       r'cannot be simulated at it: .* puts the latched arm at 17 degrees: it '
                       r'must lie in \[0, 15\]'):
        scene_for_conditions(seated, {'contact_angle_deg': 12})


def test_a_session_draws_each_latching_about_the_scene_at_the_trials_conditions(rig):
    robots = SessionRobots(rig, 3)
    at_19 = scene_for_conditions(rig, {'d_t_mm': 19.0})
    for n in range(1, 6):
        own, drawn = robots(n), robots(n, at_19)
        # the same draw for the latching, on the robot of the conditions
        assert drawn.geometry.latch_offset_deg == own.geometry.latch_offset_deg
        assert drawn.geometry.d_t_mm == 19.0 and own.geometry.d_t_mm == 23.0
        assert drawn == scene_for_conditions(own, {'d_t_mm': 19.0})
    # the latch's range follows the base's contact angle: the arm stays within [0, 15] degrees
    steep = scene_for_conditions(rig, {'contact_angle_deg': 14.5})
    own = [robots(n).geometry.latch_offset_deg for n in range(1, 41)]
    drawn = [robots(n, steep).geometry.latch_offset_deg for n in range(1, 41)]
    assert max(drawn) <= 0.5 < max(own)                  # 14.5 + 0.5: the latch's end
    assert min(drawn) < -3.0 == min(own)                 # 3 - 3: the body's
    assert sum(a == b for a, b in zip(own, drawn)) > 20  # the same draws in between
