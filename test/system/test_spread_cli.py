"""The spread from the command line: `mantis identify --spread` fits it into the scenes,
`mantis compare --spread N` forecasts real strikes from it and scores the forecasts, `mantis sim
--spread N` gives a design's quantiles; each seeded, each refusing what it cannot do."""
import csv
import json

from conftest import data_file
import numpy as np
import pytest

from mantis_rig.cli import main as mantis
from mantis_sim.robots import DESIGN_METRICS
from mantis_sim.scene import load_scene, load_scene_file

TABLE = 'real_trials/authors_summary_train.csv'
LEVELS = [f'q{5 * k:02d}' for k in range(1, 20)]


def compare(out, *extra):
    return mantis(['compare', '--strikes', str(data_file(TABLE)), '--out', str(out),
                   '--workers', '0', '--group', 'water_23mm', *extra])


def test_compare_forecasts_each_strike_with_its_quantiles_and_scores_them(tmp_path, capsys):
    assert compare(tmp_path / 'a', '--spread', '8', '--seed', '3', '--json') == 0
    report = json.loads(capsys.readouterr().out)
    with open(tmp_path / 'a' / 'predictions.csv') as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 6 and {r['group'] for r in rows} == {'water_23mm'}
    columns = ['trial', 'group', 'day_seen']
    for stem in ('tip_speed_mps', 'spring_energy_mJ'):
        columns += [f'{stem}_measured'] + [f'{stem}_{q}' for q in LEVELS]
    assert list(rows[0]) == columns + ['robots_not_struck']
    # the training strikes' days are the spread's own: each forecast from its day's assembly
    assert {r['day_seen'] for r in rows} == {'True'}
    assert report['spread']['strikes_on_days_seen'] == 6
    for row in rows:
        q = [float(row[f'tip_speed_mps_{level}']) for level in LEVELS]
        assert q == sorted(q) and 3.5 < q[9] < 6.0          # a strike in water: ~4.6 m/s
    scores = report['spread']['scores']
    for metric in ('peak_tip_speed_mps', 'spring_energy_mJ'):
        entry = scores[metric]['water_23mm']
        assert entry['strikes'] == 6 and 0.0 <= entry['coverage_50'] <= entry['coverage_80']
        assert entry['crps'] > 0 and entry['crps_climatology'] > 0
    with open(tmp_path / 'a' / 'spread_scores.csv') as handle:
        assert {(r['metric'], r['group']) for r in csv.DictReader(handle)} == {
            (m, g) for m in ('peak_tip_speed_mps', 'spring_energy_mJ')
            for g in ('water_23mm', 'all')}
    assert (tmp_path / 'a' / 'forecasts.png').stat().st_size > 10_000
    # the seed fixes every robot: again, the same table; another seed, another
    assert compare(tmp_path / 'b', '--spread', '8', '--seed', '3', '--json') == 0
    assert compare(tmp_path / 'c', '--spread', '8', '--seed', '4', '--json') == 0
    capsys.readouterr()
    text = {k: (tmp_path / k / 'predictions.csv').read_text() for k in 'abc'}
    assert text['a'] == text['b'] != text['c']


@pytest.mark.parametrize('extra, message', [
    (['--spread', '1'], 'at least 2 robots'),
    (['--spread', '5', '--at-seat'], 'use one or the other'),
    (['--spread', '5', '--scene', 'water_23mm=reference_water_23mm'],
     'no spread in the scene of water_23mm'),
])
def test_compare_refuses_a_spread_it_cannot_draw(tmp_path, capsys, extra, message):
    assert compare(tmp_path / 'o', *extra) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'o').exists()


def test_sim_gives_every_metric_s_quantiles_for_the_seed(capsys):
    args = ['sim', '--scene', 'air_23mm', '--set', 'geometry.d_t_mm=21', '--spread', '12',
            '--json']
    assert mantis(args + ['--seed', '5']) == 0
    first = json.loads(capsys.readouterr().out)
    assert first['robots'] == 12 and first['not_struck'] == 0
    assert set(first['quantiles']) == set(DESIGN_METRICS)
    for metric, table in first['quantiles'].items():
        values = [table[level] for level in LEVELS]
        assert values == sorted(values) and np.isfinite(values).all(), metric
    assert mantis(args + ['--seed', '5']) == 0
    assert json.loads(capsys.readouterr().out) == first
    assert mantis(['sim', '--scene', 'air_23mm', '--spread', '12']) == 0
    text = capsys.readouterr().out
    assert '12 robots drawn from its spread, a new day\'s assembly each (seed 1)' in text
    assert sum(line.startswith(tuple(LEVELS)) for line in text.splitlines()) == 19


def test_sim_draws_the_robots_of_a_day_the_spread_has_seen(capsys):
    """Air at 23 mm: the arm sat about 8.7 degrees further on 0828019, about -2.7 on 031320
    (docs/spread_benchmark.md): far less stored energy on the first day's robots."""
    def median_energy(*day):
        assert mantis(['sim', '--scene', 'air_23mm', '--spread', '12', '--json', *day]) == 0
        report = json.loads(capsys.readouterr().out)
        assert report['day'] == (day[1] if day else None)
        return report['quantiles']['spring_energy_mJ']['q50']
    far, near, new = (median_energy('--day', '0828019'), median_energy('--day', '031320'),
                      median_energy())
    assert far < new < near and near - far > 20.0


@pytest.mark.parametrize('args, message', [
    (['--scene', 'reference_air_23mm', '--spread', '5'], 'no spread in the scene of'),
    (['--scene', 'air_23mm', '--spread', '0'], 'at least 2 robots'),
    (['--scene', 'air_23mm', '--spread', '5', '--plot', 'x.png'], 'for one simulation'),
    (['--scene', 'air_23mm', '--spread', '5', '--day', '20261127'],
     'has not seen recording day 20261127 (it knows: 031320, 0801319'),
    (['--scene', 'air_23mm', '--day', '0828019'], '--day names the recording day'),
])
def test_sim_refuses_a_spread_it_cannot_draw(capsys, args, message):
    assert mantis(['sim', *args]) == 2
    assert message in capsys.readouterr().err


def test_identify_fits_the_spread_into_the_scene_and_compare_draws_from_it(tmp_path, capsys):
    out = tmp_path / 'scenes'
    code = mantis(['identify', '--strikes', str(data_file(TABLE)), '--group', 'water_23mm',
                   '--spread', '--out', str(out), '--workers', '0', '--json'])
    assert code == 0
    report = json.loads(capsys.readouterr().out)['spread']
    assert report['strikes'] == 6 and report['days'] == 2
    assert len(report['strike_latents']) == 6
    scene = load_scene_file(out / 'water_23mm.yaml')
    assert scene.spread.latent.mean == pytest.approx(report['means']['water_23mm']['value'],
                                                     rel=1e-5)
    assert scene.spread.provenance['strikes'] == 6
    assert len(scene.spread.climatology['spring_energy_mJ']) == 6
    # the parameters were kept: the scene's robot is the shipped one
    shipped = load_scene('water_23mm')
    assert scene.tendon == shipped.tendon and scene.hinge == shipped.hinge
    assert compare(tmp_path / 'cmp', '--spread', '4', '--scene',
                   f'water_23mm={out / "water_23mm.yaml"}') == 0


def test_sweep_gives_each_design_its_quantiles_and_the_plot_weighs_effects_against_them(
        tmp_path, capsys):
    out = tmp_path / 'study.parquet'
    args = ['sweep', '--scene', 'air_23mm', '--vary', 'geometry.d_t_mm=19:25:3', '--vary',
            'drive.pull_speed_mm_per_s=0.5:2.5:2', '--spread', '10', '--out', str(out),
            '--workers', '0', '--quiet']
    assert mantis(args) == 0
    from mantis_sim.studies.design.sweep import read_table
    rows = read_table(out)
    assert len(rows) == 6 and all(r['spread_robots'] == 10 for r in rows)
    for row in rows:
        for metric in ('peak_tip_speed_mps', 'spring_energy_mJ', 'peak_tendon_force_N'):
            q = [row[f'{metric}_{level}'] for level in LEVELS]
            assert q == sorted(q), metric
    # the same robots at every design: the pull speed moves no quantile by much
    by_guide = {}
    for row in rows:
        by_guide.setdefault(row['geometry.d_t_mm'], []).append(row['peak_tip_speed_mps_q50'])
    assert all(abs(a - b) < 0.05 for a, b in by_guide.values())
    # a rerun with another seed computes every design again; with the same, none
    capsys.readouterr()
    assert mantis(args + ['--spread-seed', '2']) == 0
    assert '6 computed, 0 from the earlier table' in capsys.readouterr().err
    assert mantis(args + ['--spread-seed', '2']) == 0
    assert '0 computed, 6 from the earlier table' in capsys.readouterr().err
    assert mantis(['sweep-plot', str(out), '--out', str(tmp_path / 'figs')]) == 0
    text = capsys.readouterr().out
    assert (tmp_path / 'figs' / 'intervals_peak_tip_speed_mps.png').stat().st_size > 10_000
    with open(tmp_path / 'figs' / 'spread_effects.csv') as handle:
        effects = {e['key']: e for e in csv.DictReader(handle)}
    assert set(effects) == {'geometry.d_t_mm', 'drive.pull_speed_mm_per_s'}
    guide = effects['geometry.d_t_mm']
    assert float(guide['change_of_median']) < 0 < float(guide['one_strike_sd'])
    assert 'geometry.d_t_mm 19 to 25: the median peak_tip_speed_mps changes by' in text
    assert 'strikes per design (80 % power, 5 % level)' in text


def test_sweep_refuses_a_spread_the_scene_lacks(tmp_path, capsys):
    code = mantis(['sweep', '--scene', 'reference_air_23mm', '--vary',
                   'geometry.d_t_mm=19:25:3', '--spread', '10', '--out',
                   str(tmp_path / 'x.parquet'), '--workers', '0', '--quiet'])
    assert code == 2
    assert 'no spread in the scene of reference_air_23mm' in capsys.readouterr().err


def test_compare_writes_into_compare_here_unless_told(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert mantis(['compare', '--strikes', str(data_file(TABLE)), '--group', 'water_23mm',
                   '--spread', '2', '--workers', '0']) == 0
    assert (tmp_path / 'compare' / 'predictions.csv').exists()
    assert 'outputs: compare/errors.csv' in capsys.readouterr().out


def test_identify_refuses_a_spread_from_one_day(tmp_path, capsys):
    lines = data_file(TABLE).read_text().splitlines()
    one_day = [lines[0]] + [line for line in lines[1:] if ',011620,' in line]
    table = tmp_path / 'one_day.csv'
    table.write_text('\n'.join(one_day) + '\n')
    code = mantis(['identify', '--strikes', str(table), '--spread', '--out',
                   str(tmp_path / 'scenes'), '--workers', '0'])
    assert code == 2
    assert 'the spread needs strikes of at least two recording days' in capsys.readouterr().err
    assert not (tmp_path / 'scenes').exists()
