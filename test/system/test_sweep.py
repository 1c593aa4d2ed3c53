"""`mantis sweep` (issue 14): the same table from this process, a LocalCluster and a real
scheduler with two workers; a worker killed in mid-sweep loses no design; a rerun computes only
what is missing; bad input is refused before any work; failed designs are rows with a reason."""
import os
from pathlib import Path
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from mantis_rig.cli import main as cli_main
from mantis_sim.studies.design.designs import grid, parse_range
from mantis_sim.studies.design.sweep import read_table, run_sweep
from mantis_sim.studies.design.sweep_plots import pareto_front

SCENE = 'reference_air_23mm'
FIXED = ['integration.solver=LSODA', 'integration.rtol=0.001']
VARY = ['geometry.d_t_mm=19:25:4', 'geometry.contact_angle_deg=1:8:3']
DASK = Path(sys.executable).with_name('dask')

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]


def designs():
    return grid([parse_range(v) for v in VARY])


def comparable(rows):
    """Every column but the wall times of each design, which no two runs share."""
    return [{k: v for k, v in row.items() if k not in ('wall_time_s', 'design_time_s')}
            for row in rows]


@pytest.fixture(scope='module')
def serial_table(tmp_path_factory):
    out = tmp_path_factory.mktemp('sweep') / 'serial.parquet'
    summary = run_sweep(SCENE, FIXED, designs(), out, workers=0, progress=False)
    assert summary.computed == 12 and summary.ok == 12
    return read_table(out)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


@pytest.fixture
def dask_cluster(tmp_path):
    """A `dask scheduler` and two `dask worker` processes on the loopback address."""
    port = free_port()
    address = f'tcp://127.0.0.1:{port}'
    env = {**os.environ, 'DASK_DISTRIBUTED__WORKER__DAEMON': 'False'}
    log = open(tmp_path / 'dask.log', 'wb')
    processes = [subprocess.Popen([str(DASK), 'scheduler', '--host', '127.0.0.1', '--port',
                                   str(port), '--no-dashboard'], stdout=log, stderr=log,
                                  env=env)]
    for _ in range(2):
        processes.append(subprocess.Popen(
            [str(DASK), 'worker', address, '--nthreads', '1', '--nworkers', '1', '--host',
             '127.0.0.1', '--no-dashboard'], stdout=log, stderr=log, env=env))
    from dask.distributed import Client
    client = Client(address, timeout=60)
    client.wait_for_workers(2, timeout=60)
    client.close()
    try:
        yield address, processes[1:]
    finally:
        for process in reversed(processes):
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
        for process in processes:          # a worker takes ~8 s to leave on SIGTERM
            try:
                process.wait(timeout=1)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        log.close()


def test_local_cluster_gives_the_serial_table_to_the_last_digit(serial_table, tmp_path):
    out = tmp_path / 'local.parquet'
    summary = run_sweep(SCENE, FIXED, designs(), out, workers=2, chunk_size=2, progress=False)
    assert summary.workers == 2 and summary.computed == 12
    assert comparable(read_table(out)) == comparable(serial_table)


def test_a_scheduler_and_two_workers_give_the_serial_table(serial_table, dask_cluster,
                                                          tmp_path):
    address, _ = dask_cluster
    out = tmp_path / 'cluster.parquet'
    code = cli_main(['sweep', '--scene', SCENE, *sum((['--set', s] for s in FIXED), []),
                     *sum((['--vary', v] for v in VARY), []), '--out', str(out),
                     '--scheduler', address, '--quiet'])
    assert code == 0
    assert comparable(read_table(out)) == comparable(serial_table)


def test_a_worker_killed_in_mid_sweep_loses_no_design(dask_cluster, tmp_path, monkeypatch):
    """Slow designs one per task; once some are back, one worker is killed outright."""
    from mantis_sim.studies.design import sweep
    address, workers = dask_cluster
    slow = ['integration.solver=Radau', 'integration.rtol=1e-7']
    many = grid([parse_range('geometry.d_t_mm=19:25:12'),
                 parse_range('geometry.contact_angle_deg=1:8:3')])
    out = tmp_path / 'killed.parquet'
    killed = []
    advance = sweep.Progress.advance

    def advance_then_kill(self, n):
        advance(self, n)
        if self.done >= 4 and not killed:
            workers[0].kill()
            killed.append(time.monotonic())

    monkeypatch.setattr(sweep.Progress, 'advance', advance_then_kill)
    summary = run_sweep(SCENE, slow, many, out, scheduler=address, chunk_size=1,
                        progress=True)
    assert killed, 'the worker was never killed'
    rows = read_table(out)
    assert summary.computed == len(many) == len(rows) == 36
    assert [r['geometry.d_t_mm'] for r in rows] == [d['geometry.d_t_mm'] for d in many]
    reference = tmp_path / 'reference.parquet'
    run_sweep(SCENE, slow, many, reference, workers=0, progress=False)
    assert comparable(rows) == comparable(read_table(reference))


def test_a_rerun_computes_only_the_missing_designs(serial_table, tmp_path):
    out = tmp_path / 'resumed.parquet'
    first = run_sweep(SCENE, FIXED, designs()[:5], out, workers=0, progress=False)
    assert first.computed == 5
    again = run_sweep(SCENE, FIXED, designs(), out, workers=0, progress=False)
    assert (again.computed, again.reused) == (7, 5)
    assert comparable(read_table(out)) == comparable(serial_table)


def test_a_design_that_fails_is_a_row_with_its_reason(tmp_path):
    out = tmp_path / 'failing.parquet'
    bad = [{'spring.k_Nmm_per_rad': 0.01}, {'drive.start_position_mm': 24.9},
           {'spring.k_Nmm_per_rad': 47.7}]
    summary = run_sweep(SCENE, FIXED, bad, out, workers=0, progress=False)
    rows = read_table(out)
    assert [r['status'] for r in rows] == ['failed', 'no strike', 'ok']
    assert 'is not held by the tendon and the latch' in rows[0]['reason']
    assert rows[1]['reason'].startswith('the stage used up its travel (0.1 mm from '
                                        'drive.start_position_mm = 24.9')
    assert summary.ok == 1


@pytest.mark.parametrize('args, message', [
    (['--vary', 'geometry.nope=1:2:3'], 'unknown key geometry.nope'),
    (['--vary', 'geometry.d_t_mm=-5:20:3'], 'geometry.d_t_mm = -5.0 is out of range; valid '
                                             'range [1, 100] mm'),
    (['--vary', 'geometry.d_t_mm=19:25'], 'a grid needs N >= 1 points'),
    (['--vary', 'medium.name=1:2:2'], 'medium.name = 1.0 is not valid'),
    (['--vary', 'geometry.d_t_mm=19:25:3', '--scheduler', 'tcp://127.0.0.1:{port}'],
     'cannot reach the Dask scheduler'),
    (['--vary', 'geometry.d_t_mm=19:25:3', '--accuracy', '2'], '--accuracy 2: a relative '
                                                                'error between 0 and 1'),
])
def test_bad_input_is_refused_before_any_work(tmp_path, capsys, args, message):
    out = tmp_path / 'never.parquet'
    args = [a.format(port=free_port()) for a in args]
    code = cli_main(['sweep', '--scene', SCENE, '--out', str(out), '--quiet', *args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert message in err and err.count('\n') == 1 and err.startswith('mantis sweep: '), err
    assert not out.exists()


def test_accuracy_picks_the_cheapest_setting_that_reaches_it(tmp_path, capsys):
    out = tmp_path / 'accuracy.parquet'
    code = cli_main(['sweep', '--scene', SCENE, '--vary', 'geometry.d_t_mm=21:23:2',
                     '--accuracy', '1e-3', '--out', str(out), '--workers', '0', '--quiet'])
    err = capsys.readouterr().err
    assert code == 0, err
    chosen = [line for line in err.splitlines() if '--accuracy 0.001:' in line][0]
    rows = read_table(out)
    assert f'{rows[0]["solver"]} at rtol {rows[0]["rtol"]:g}' in chosen
    error = float(chosen.split('within ')[1].split(' of')[0])
    assert error * 3 <= 1e-3
    assert rows[0]['solver'] == 'fast' and 'sampled designs' in chosen


def test_sweep_plot_writes_the_figures_and_the_best_designs(serial_table, tmp_path):
    from mantis_sim.studies.design.sweep import write_table
    table = tmp_path / 'study.parquet'
    write_table(serial_table, table)
    code = cli_main(['sweep-plot', str(table), '--out', str(tmp_path / 'figs'),
                     '--force-limit', '17.5', '--top', '3'])
    assert code == 0
    for name in ('heatmap_peak_tip_speed_mps.png', 'pareto.png', 'best_designs.csv'):
        assert (tmp_path / 'figs' / name).stat().st_size > 0, name
    best = (tmp_path / 'figs' / 'best_designs.csv').read_text().splitlines()
    assert len(best) == 4 and best[0].startswith('design_id,geometry.d_t_mm,')
    speeds = [float(line.split(',')[3]) for line in best[1:]]
    assert speeds == sorted(speeds, reverse=True)
    forces = [float(line.split(',')[4]) for line in best[1:]]
    assert max(forces) <= 17.5


def test_pareto_front():
    force = np.array([10.0, 12.0, 11.0, 15.0, 12.0])
    speed = np.array([20.0, 25.0, 19.0, 24.0, 26.0])
    assert list(pareto_front(force, speed)) == [0, 4]
