"""`mantis study attach`: a tracked video's export fills its trial's tip speed and energy, matched
by the name the study gave it, and the row is judged against its forecast; an export that
matches no trial is refused with the names the study expects, and nothing is written."""
import shutil

from conftest import data_file
import pytest
from study_records import two_trials_done

from mantis_rig.cli.main import main
from mantis_rig.study_session.attach import attach_exports
from mantis_rig.study_session.record import read_record
from mantis_sim.errors import InputError

EXPORT = 'real_trials/air_23mm_19kfps_pair_track.csv'      # the authors: 22.96 m/s, 78.1 mJ


def test_an_export_fills_its_trial_and_is_judged(tmp_path):
    directory = two_trials_done(tmp_path)
    export = tmp_path / 'guide_run002_trial002.csv'
    shutil.copy(data_file(EXPORT), export)
    said = []
    assert attach_exports(directory, [export], say=said.append) == 1
    first, second = read_record(directory / 'study.csv').rows
    assert first['peak_tip_speed_mps'] is None
    assert second['peak_tip_speed_mps'] == pytest.approx(22.96, rel=0.05)
    assert second['max_spring_energy_mJ'] == pytest.approx(78.1, rel=0.15)
    assert 0.0 <= second['peak_tip_speed_mps_pit'] <= 1.0
    assert second['peak_tip_speed_mps_flag'] in ('inside', 'outside')
    assert second['peak_tip_speed_mps_q05'] < second['peak_tip_speed_mps_q95']
    assert any('run 2' in line for line in said)


def test_an_export_of_no_trial_is_refused_and_nothing_written(tmp_path):
    directory = two_trials_done(tmp_path)
    before = (directory / 'study.csv').read_text()
    export = tmp_path / 'guide_run009_trial009.csv'
    shutil.copy(data_file(EXPORT), export)
    with pytest.raises(InputError, match="no trial of the study .* is named 'guide_run009"):
        attach_exports(directory, [export])
    assert (directory / 'study.csv').read_text() == before
    assert main(['study', 'attach', str(directory), str(export)]) == 2


def test_a_bad_plan_ends_the_command_with_one_line_per_mistake(tmp_path, capsys):
    plan = tmp_path / 'plan.yaml'
    plan.write_text('scene: air_23mm_rig\nfactors: {d_t_mm: [19, 250]}\nrepeats: 2\n'
                    'order: sideways\n')
    assert main(['study', str(plan), '--out', str(tmp_path / 'out')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith('mantis study: ') and 'the plan cannot run' in err[0]
    assert any('d_t_mm = 250.0 mm is outside' in line for line in err)
    assert any("order: 'sideways'" in line for line in err)
    assert not (tmp_path / 'out').exists()
