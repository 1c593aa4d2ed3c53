"""The study's analyst: one worker process, started fresh (spawn), that simulates the twin's
forecast ensembles and measures each trial's bag (and, in a study whose plan says
``video: true``, waits for its film and tracks it) while the rig runs the next trial, and
writes the report while the rig's stack shuts down. It runs on the CPU the rig leaves idle
(Linux's SCHED_IDLE; elsewhere niceness 10), with one BLAS thread: a trial in progress keeps
the machine first. Results come back in the order the work was asked for."""
from __future__ import annotations

from concurrent.futures import Future, ProcessPoolExecutor
import multiprocessing
import os
from pathlib import Path
import signal

NICENESS = 10


def _start_worker(parent_pid: int) -> None:
    # The study's process stops the study on Ctrl-C; the terminal sends it to the worker too,
    # which is ended by its pool, not by a traceback of its own. A study process that is
    # killed outright leaves no worker behind: the worker ends itself once its parent is gone.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from mantis_rig.runtime.stopping import watch_parent
    watch_parent(parent_pid)
    try:           # only the CPU the rig leaves idle: a trial in progress is never slowed
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        try:
            os.nice(NICENESS)
        except OSError:
            pass
    from mantis_sim.studies.shared.blas import one_blas_thread
    one_blas_thread()


def _ensemble(scene_name: str, overrides: list, conditions: dict, robots: int, seed: int,
              slack_force_N: float):
    from mantis_sim.scene import load_scene
    from mantis_sim.studies.rig_study.twin_forecast import simulate_ensemble
    scene = load_scene(scene_name, overrides)
    return simulate_ensemble(scene, conditions, robots, seed, slack_force_N=slack_force_N)


def _measure(bag: str) -> dict:
    from mantis_rig.study_session.measure import measure_trial
    try:
        return measure_trial(Path(bag))
    except Exception as exc:  # noqa: BLE001 - a bag that cannot be read is its row's note, not the study's end
        return {'analysis_note': f'cannot measure {bag}: {type(exc).__name__}: {exc}'}


def _measure_filmed(bag: str, tracks_csv: str) -> dict:
    from mantis_rig.study_session.measure import measure_filmed_trial
    try:
        return measure_filmed_trial(Path(bag), Path(tracks_csv))
    except Exception as exc:  # noqa: BLE001 - as _measure: the row's note
        return {'analysis_note': f'cannot measure {bag} from its film: '
                                 f'{type(exc).__name__}: {exc}'}


def _report(directory: str) -> tuple[str, list]:
    from mantis_rig.study_session.report import write_report
    said: list = []
    path = write_report(Path(directory), say=said.append)
    return str(path), said


class Analyst:
    def __init__(self):
        self._pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context('spawn'),
                                         initializer=_start_worker, initargs=(os.getpid(),))

    def ensemble(self, scene_name: str, overrides: list, conditions: dict, robots: int,
                 seed: int, slack_force_N: float) -> Future:
        return self._pool.submit(_ensemble, scene_name, list(overrides), dict(conditions),
                                 robots, seed, slack_force_N)

    def measure(self, bag: Path) -> Future:
        return self._pool.submit(_measure, str(bag))

    def measure_filmed(self, bag: Path, tracks_csv: Path) -> Future:
        """The trial's measurement, its tip speed and energy from its film (waited for, then
        tracked into ``tracks_csv``) instead of its bag's marker frames."""
        return self._pool.submit(_measure_filmed, str(bag), str(tracks_csv))

    def report(self, directory: Path) -> Future:
        """The study's report, written while the rig's stack shuts down: (its folder, the
        lines it has to say)."""
        return self._pool.submit(_report, str(directory))

    def close(self, wait: bool = True) -> None:
        """Wait for the work asked for, or (``wait`` False) drop it and end the worker now."""
        workers = list(getattr(self._pool, '_processes', {}).values())
        self._pool.shutdown(wait=wait, cancel_futures=not wait)
        if not wait:
            for worker in workers:
                worker.terminate()
                worker.join(5.0)


__all__ = ['Analyst']
