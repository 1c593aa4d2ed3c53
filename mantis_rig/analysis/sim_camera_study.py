"""What the analysis recovers from the simulated camera, against the simulated world's truth.

A simulated trial films the strike through the scene's camera: frames on a fixed grid of the
world's clock, marker positions quantised to its pixels (effect camera_sampling). Where the
strike falls between two frames (the frame phase) changes every quantisation error at once,
so one trial measures one draw. This study runs the world through one strike (no ROS), films
it at several frame phases and analyses each film as `mantis analyze` would analyse the bag
(the scene's geometry and contact angle as the bag's trial conditions give them), giving the
spread of every error over the phases. ``bench/bench_sim_camera.py`` prints it; the tests
bound it.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from mantis_rig.analysis.bag_conditions import params_for_trial
from mantis_sim.results import simulate
from mantis_sim.scene import Scene, load_scene
from mantis_sim.sensors import CameraSensor
from mantis_sim.world import World

from .inputs import MarkerTracks
from .pipeline import analyze_tracks

PHASES = ('II', 'III', 'IV')
# The world advances in steps like the trial's world runner; the strike is found on them.
WORLD_STEP_S = 0.01


@dataclass
class StrikeTruth:
    """The simulated world's own phase starts and peak (s), and the batch simulation's peak
    tip speed (m/s: the same physics as the world, see test_analysis_sim_trial)."""

    phase_start_s: dict
    peak_time_s: float
    peak_tip_speed_mps: float


@dataclass
class FilmErrors:
    """One film's analysis minus the truth: times in frames, the peak speed relative."""

    frame_phase: float
    phase_frames: dict              # 'II', 'III', 'IV' -> error in frames
    peak_time_frames: float
    peak_tip_speed_rel: float


def run_strike(scene: Scene, pull_start_s: float = 0.5, after_peak_s: float = 0.03,
               history_s: float = 5.0) -> World:
    """A World pulled at the scene's speed from ``pull_start_s`` until past its strike."""
    world = World(scene, history_s=history_s)
    world.advance_to(pull_start_s)
    world.set_stage_velocity(scene.drive.pull_speed_mm_per_s * 1e-3)
    t_s = pull_start_s
    while not math.isfinite(world.peak_time_s):
        if t_s - pull_start_s > history_s:
            raise RuntimeError(f'scene {scene.name!r}: no strike within {history_s} s of pulling')
        t_s += WORLD_STEP_S
        world.advance_to(t_s)
    world.advance_to(world.peak_time_s + after_peak_s)
    return world


def film(world: World, frame_rate_hz: float, frame_phase: float, before_s: float = 0.3,
         after_s: float = 0.02) -> MarkerTracks:
    """The scene's camera filming from ``before_s`` before the start of phase IV to
    ``after_s`` after it; ``frame_phase`` in [0, 1) shifts the frame grid by that share of
    a frame period."""
    t_iv = world.phase_start_s['IV']
    first = math.ceil((t_iv - before_s) * frame_rate_hz)
    count = int(round((before_s + after_s) * frame_rate_hz))
    times = (first + frame_phase + np.arange(count)) / frame_rate_hz
    # Each film its own draw of the tracking noise, reproducible from its phase.
    seed = int(round(frame_phase * 1e6))
    markers_m = CameraSensor(world.scene, seed).image(world.marker_positions_m(times))
    return MarkerTracks(time_s=times, frames=np.arange(count),
                        markers_mm={name: xy * 1e3 for name, xy in markers_m.items()},
                        handedness='left', source={'format': 'simulated camera'})


def truth_of(world: World) -> StrikeTruth:
    batch = simulate(world.scene).metrics
    return StrikeTruth(dict(world.phase_start_s), world.peak_time_s,
                       batch['peak_tip_speed_mps'])


def analysis_params(scene: Scene):
    """The parameters `mantis analyze` takes for a bag of this scene: the scene's, with the
    guide distance and contact angle its trial conditions record."""
    g = scene.geometry
    return params_for_trial({'scene': scene.name, 'd_t_mm': g.d_t_mm,
                             'contact_angle_deg': g.latched_angle_deg})[0]


def film_errors(world: World, truth: StrikeTruth, frame_rate_hz: float,
                frame_phase: float, before_s: float = 0.3) -> FilmErrors:
    """Analyse one film as `mantis analyze` analyses a bag of this scene; errors vs truth."""
    params = analysis_params(world.scene)
    summary = analyze_tracks(film(world, frame_rate_hz, frame_phase, before_s),
                             params).summary()
    starts = summary['phase_start_s']
    return FilmErrors(
        frame_phase=frame_phase,
        phase_frames={p: (starts[p] - truth.phase_start_s[p]) * frame_rate_hz for p in PHASES},
        peak_time_frames=(summary['peak_tip_speed_s'] - truth.peak_time_s) * frame_rate_hz,
        peak_tip_speed_rel=summary['peak_tip_speed_mps'] / truth.peak_tip_speed_mps - 1.0)


def phase_sweep(world: World, truth: StrikeTruth, frame_rate_hz: float, n_phases: int,
                before_s: float = 0.3) -> list[FilmErrors]:
    """The errors of ``n_phases`` films at evenly spaced frame phases."""
    return [film_errors(world, truth, frame_rate_hz, k / n_phases, before_s)
            for k in range(n_phases)]


def study(scene_name: str = 'air_23mm_rig', frame_rate_hz: float | None = None,
          n_phases: int = 8, before_s: float = 0.3) -> tuple[StrikeTruth, list[FilmErrors]]:
    """One strike of the scene: its truth and :func:`phase_sweep` at the scene's frame rate
    (or ``frame_rate_hz``)."""
    scene = load_scene(scene_name)
    world = run_strike(scene)
    truth = truth_of(world)
    return truth, phase_sweep(world, truth, frame_rate_hz or scene.camera.frame_rate_hz,
                              n_phases, before_s)


@dataclass
class IntervalCoverage:
    """How often the analysis's 80 % intervals (analysis.intervals) hold the world's truth,
    per quantity, over films at evenly spaced frame phases (each its own noise draw)."""

    films: int
    replicas: int
    held: dict                  # quantity -> films whose interval held the truth
    widths: dict                # quantity -> median interval width (its unit)
    errors: dict                # quantity -> median error of the analysis's value

    def coverage(self, key: str) -> float:
        return self.held[key] / self.films


def interval_coverage(scene_name: str = 'air_23mm_rig', films: int = 20,
                      replicas: int = 30, overrides: tuple = ()) -> IntervalCoverage:
    """One strike of the scene (with ``overrides``, KEY=VALUE) filmed ``films`` times, each
    analysed with its intervals."""
    from .intervals import QUANTITIES, track_intervals, value_of
    scene = load_scene(scene_name, list(overrides))
    world = run_strike(scene)
    truth = truth_of(world)
    params = analysis_params(scene)
    true = {'peak_tip_speed_mps': truth.peak_tip_speed_mps,
            'max_spring_energy_mJ': simulate(scene).metrics['max_spring_energy_mJ'],
            **{f'phase_start_s.{p}': truth.phase_start_s[p] for p in PHASES}}
    held = {key: 0 for key in QUANTITIES}
    widths = {key: [] for key in QUANTITIES}
    errors = {key: [] for key in QUANTITIES}
    for k in range(films):
        tracks = film(world, scene.camera.frame_rate_hz, k / films)
        result = analyze_tracks(tracks, params)
        found = track_intervals(tracks, result, replicas, seed=k)
        summary = result.summary()
        for key, interval in found.quantities.items():
            held[key] += interval.holds(true[key])
            widths[key].append(interval.high - interval.low)
            errors[key].append(value_of(summary, key) - true[key])
    return IntervalCoverage(films, replicas, held,
                            {k: float(np.median(v)) for k, v in widths.items()},
                            {k: float(np.median(v)) for k, v in errors.items()})

