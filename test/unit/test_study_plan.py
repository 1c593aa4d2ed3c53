"""A study's plan: read, checked (every mistake named), and put in its run order."""
from collections import Counter

import pytest

from mantis_rig.trial.supervisor_settings import check_value
from mantis_sim.studies.rig_study.plan import PlanError, load_plan, plan_from_mapping

BINDING = """
scene: air_23mm_rig
factors:
  d_t_mm: [19, 25]
  pull_speed_mm_s: [1.0, 2.3]
repeats: 4
order: random
seed: 5
"""


def _plan(tmp_path, text):
    path = tmp_path / 'plan.yaml'
    path.write_text(text)
    return load_plan(path, check_condition=check_value)


def test_the_issues_plan_reads_and_runs_every_combination_four_times(tmp_path):
    plan = _plan(tmp_path, BINDING)
    trials = plan.trials()
    assert len(trials) == 16
    cells = Counter((t.conditions['d_t_mm'], t.conditions['pull_speed_mm_s']) for t in trials)
    assert set(cells.values()) == {4} and len(cells) == 4
    assert sorted(t.trial for t in trials) == list(range(1, 17))
    assert [t.trial for t in trials] == [t.trial for t in plan.trials()]   # seeded


def test_random_order_is_not_the_listed_one_and_changes_with_the_seed(tmp_path):
    plan = _plan(tmp_path, BINDING)
    listed = plan_from_mapping({**plan.to_mapping(), 'order': 'as-listed'}, 'x')
    assert [t.trial for t in listed.trials()] == list(range(1, 17))
    other = plan_from_mapping({**plan.to_mapping(), 'seed': 6}, 'x')
    assert [t.trial for t in plan.trials()] != list(range(1, 17))
    assert [t.trial for t in plan.trials()] != [t.trial for t in other.trials()]


def test_split_plot_changes_the_guide_once_per_level(tmp_path):
    plan = _plan(tmp_path, BINDING.replace('order: random', 'order: split-plot'))
    trials = plan.trials()
    guides = [t.conditions['d_t_mm'] for t in trials]
    changes = sum(a != b for a, b in zip(guides, guides[1:]))
    assert changes == 1                          # levels - 1: as few as the design allows
    assert [t.block for t in trials] == [1] * 8 + [2] * 8
    speeds = [t.conditions['pull_speed_mm_s'] for t in trials[:8]]
    assert speeds != sorted(speeds)              # randomised within the block


def test_the_plan_round_trips_through_its_mapping(tmp_path):
    plan = _plan(tmp_path, BINDING + 'fixed: {contact_angle_deg: 4.0}\n')
    again = plan_from_mapping(plan.to_mapping(), 'again')
    assert again == plan
    assert all(t.conditions['contact_angle_deg'] == 4.0 for t in plan.trials())


def test_a_bad_plan_names_every_mistake_one_line_each(tmp_path):
    text = """
scene: air_23mm_rig
factors:
  d_t_mm: [19, 19]
  pull_speed_mm_s: [1.0, 9.0]
  guide: [1]
repeats: 0
order: sideways
fixed: {medium: 3}
colour: blue
"""
    with pytest.raises(PlanError) as caught:
        _plan(tmp_path, text)
    lines = str(caught.value).splitlines()
    message = str(caught.value)
    assert lines[0].endswith('the plan cannot run:')
    for mistake in ("unknown key 'colour'", "'guide' is not a trial condition",
                    'd_t_mm: a level is listed twice', 'pull_speed_mm_s: pull_speed_mm_s = 9.0',
                    'repeats: 0', "order: 'sideways'", 'medium: level 3'):
        assert mistake in message, mistake
    assert len(lines) == 8


def test_repeats_auto_needs_the_smallest_effect(tmp_path):
    with pytest.raises(PlanError, match='smallest_effect'):
        _plan(tmp_path, BINDING.replace('repeats: 4', 'repeats: auto'))
    plan = _plan(tmp_path, BINDING.replace('repeats: 4', 'repeats: auto\nsmallest_effect: '
                                           '{peak_tip_speed_mps: 0.5}'))
    assert plan.repeats is None
    with pytest.raises(PlanError, match='resolve them'):
        plan.trials()


def test_not_yaml_and_missing_file_are_named(tmp_path):
    with pytest.raises(PlanError, match='not YAML'):
        _plan(tmp_path, 'scene: [')
    with pytest.raises(PlanError, match='cannot read the plan'):
        load_plan(tmp_path / 'missing.yaml')


def test_video_is_true_or_false_and_round_trips(tmp_path):
    assert _plan(tmp_path, BINDING).video is False
    plan = _plan(tmp_path, BINDING + 'video: true\n')
    assert plan.video is True
    assert plan.to_mapping()['video'] is True
    assert plan_from_mapping(plan.to_mapping(), 'again') == plan
    assert 'video' not in _plan(tmp_path, BINDING).to_mapping()
    with pytest.raises(PlanError, match="video: 'yes' is not true or false"):
        _plan(tmp_path, BINDING + 'video: "yes"\n')


def test_video_is_refused_on_hardware_before_a_trial_starts():
    from mantis_rig.trial.supervisor_settings import ConditionError, TrialConditions
    assert TrialConditions(video=True).validate().video
    with pytest.raises(ConditionError, match='the hardware camera records the strike itself'):
        TrialConditions(video=True, backend='hardware').validate()
