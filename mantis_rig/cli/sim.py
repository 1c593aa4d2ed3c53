"""`mantis sim`, `mantis scenes` and `mantis bench`: the simulated twin from the command line."""
from __future__ import annotations

import json
from pathlib import Path
import sys

from mantis_sim.errors import InputError
from mantis_sim.parameters import SECTIONS, describe
from mantis_sim.results import WARNINGS, simulate
from mantis_sim.scene import EFFECTS, available_scenes, load_scene
from mantis_sim.spread import DEFAULT_ROBOTS
from mantis_sim.studies.design import strike_report

from ..contract import FORCE_CEILING
from .options import check_spread_request, json_safe


def add_commands(commands) -> None:
    sim = commands.add_parser('sim', help='simulate one trial of a scene')
    sim.add_argument('--scene', required=True, help='scene name (see `mantis scenes`) or YAML path')
    sim.add_argument('--set', dest='overrides', action='append', default=[],
                     metavar='KEY=VALUE', help='override a parameter, e.g. drive.pull_speed_mm_'
                     'per_s=1.2 or effects=[joint_damping]; repeatable')
    sim.add_argument('--solver', help='integrator: RK45, RK23, DOP853, Radau, BDF, LSODA')
    sim.add_argument('--rtol', type=float, help='relative tolerance')
    sim.add_argument('--json', action='store_true', help='print the metrics as one JSON object')
    sim.add_argument('--out', type=Path, help='write the trajectory as CSV to this file')
    sim.add_argument('--plot', type=Path, help='write a PNG plot of the trial to this file')
    sim.add_argument('--spread', type=int, nargs='?', const=DEFAULT_ROBOTS, metavar='N',
                     help='draw N robots from the scene\'s spread (where the arm sits, the '
                          'identified parameters, the discrepancy: docs/spread.md) and print '
                          f'the quantiles q05..q95 of each metric (N default {DEFAULT_ROBOTS})')
    sim.add_argument('--video', type=Path, metavar='DIR',
                     help='also film the strike as the rig\'s camera does (its frame rate and '
                          'pixel size the scene\'s camera.*): DIR/video.avi (lossless), '
                          'DIR/calibration.yaml and DIR/truth.csv (each marker\'s true '
                          'position per frame)')
    sim.add_argument('--video-format', choices=('avi', 'avi-raw', 'cine'), default='avi',
                     help='with --video: avi (lossless FFV1, default), avi-raw (uncompressed, '
                          'as the camera\'s software writes it) or cine (a Phantom .cine)')
    sim.add_argument('--seed', type=int, default=1,
                     help='seed of the robots drawn by --spread and of the camera\'s sensor '
                          'noise with --video (default 1)')
    sim.add_argument('--day', metavar='RECORDING_DAY',
                     help='with --spread: robots of this recording day\'s assembly, one the '
                          'spread was fitted with (default: a new day\'s)')
    sim.set_defaults(run=run_sim)

    scenes = commands.add_parser('scenes', help='list scenes, effects and parameters')
    scenes.add_argument('--params', action='store_true', help='also list every parameter')
    scenes.set_defaults(run=run_scenes)

    bench = commands.add_parser('bench', help='benchmarks that print figures')
    bench.add_argument('which', choices=['accuracy'], help='accuracy: cost of accuracy per solver')
    bench.add_argument('--scene', action='append',
                       help='scene(s) (default reference_air_23mm, reference_water_23mm)')
    bench.add_argument('--repeats', type=int, default=5, help='runs per point (median wall time)')
    bench.add_argument('--plot', type=Path, help='PNG of the Pareto fronts')
    bench.add_argument('--markdown', action='store_true', help='print tables as Markdown')
    bench.set_defaults(run=run_bench)


def _scene_from_args(args):
    overrides = list(args.overrides)
    if args.solver:
        overrides.append(f'integration.solver={args.solver}')
    if args.rtol is not None:
        overrides.append(f'integration.rtol={args.rtol!r}')
    return load_scene(args.scene, overrides)


def ceiling_warning(peak_force_n: float) -> list[str]:
    """The rig's force ceiling (mantis_rig.contract.FORCE_CEILING, its one source) against a
    simulated peak tendon force: [] if a trial at the default ceiling would not stop."""
    name, default, top = FORCE_CEILING.name, FORCE_CEILING.default, FORCE_CEILING.range[1]
    if peak_force_n <= default:
        return []
    text = (f'peak tendon force {peak_force_n:.1f} N is above the rig\'s force ceiling '
            f'({name} = {default:g} N by default, at most {top:g} N): ')
    if peak_force_n > top:
        return [text + 'a trial on the rig stops the stage before this load']
    return [text + f'a trial stops the stage before it unless {name} is raised']


def run_sim(args) -> int:
    scene = _scene_from_args(args)
    if args.day is not None and args.spread is None:
        raise InputError('--day names the recording day of the robots --spread draws')
    if args.spread is not None:
        if args.video:
            raise InputError('--video films one strike; --spread draws many robots')
        return _run_spread(args, scene)
    result = simulate(scene)
    warnings = result.metrics[WARNINGS] + ceiling_warning(result.metrics['peak_tendon_force_N'])
    if args.out:
        strike_report.write_trajectory_csv(result, args.out)
    if args.plot:
        strike_report.plot_trial(result, args.plot)
    if args.json:
        print(json.dumps({**result.to_json_dict(), WARNINGS: warnings}))
        if not result.metrics['strike_reached']:
            print(f'no strike: {result.metrics["reason"]}', file=sys.stderr)
    else:
        print(strike_report.summary_text(result))
        for label, path in (('trajectory', args.out), ('plot', args.plot)):
            if path:
                print(f'{label}: {path}')
    for line in warnings:               # in the text, and beside the JSON on stderr
        print(f'warning: {line}', file=sys.stderr if args.json else sys.stdout)
    if args.video:
        if not result.metrics['strike_reached']:
            raise InputError(f'--video: scene {scene.name} does not strike '
                             f'({result.metrics["reason"]}): nothing to film')
        _film(args, scene)
    return 0


def _film(args, scene) -> None:
    """The strike as the rig's camera films it (its rate and pixel size the scene's)."""
    from mantis_sim.camera.render import CameraSetup, film_strike

    from ..video.to_csv import ProgressLine
    setup = CameraSetup(rate_hz=scene.camera.frame_rate_hz,
                        scale_px_per_mm=1.0 / scene.camera.pixel_mm, seed=args.seed)
    film = film_strike(scene, args.video, setup, video_format=args.video_format,
                       progress=ProgressLine('sim --video'))
    rate = f'{film.rate_hz:g} frames/s'
    print(f'video: {film.video} ({film.frame_count} frames at {rate}'
          + (f'; an .avi carries no recording rate: `mantis track {film.video} --rate '
             f'{film.rate_hz:g}`)' if film.video.suffix == '.avi' else ')'))
    print(f'calibration: {film.calibration}')
    print(f'truth: {film.truth}')


def _run_spread(args, scene) -> int:
    from mantis_sim import robots
    from mantis_sim.studies.shared.parallel import ClusterMap
    check_spread_request(args.spread, {scene.name: scene})
    if args.out or args.plot:
        raise InputError('--spread prints quantiles: --out and --plot are for one simulation')
    with ClusterMap(workers=0, progress=not args.json, unit='robots') as mapper:
        run = robots.design_spread(scene, args.spread, args.seed, mapper, args.day)
    table = run.quantiles()
    if args.json:
        print(json.dumps(json_safe({'scene': scene.name, 'robots': run.robots,
                                    'seed': args.seed, 'day': args.day,
                                    'not_struck': run.not_struck,
                                    'reasons_not_struck': list(run.reasons),
                                    'quantiles': table})))
        return 0
    print(_spread_table(scene.name, run, table, args.seed, args.day))
    return 0


def _spread_table(name: str, run, table: dict, seed: int, day: str | None) -> str:
    from mantis_sim.robots import DESIGN_METRICS
    of_day = f'recording day {day}\'s assembly' if day else 'a new day\'s assembly each'
    lines = [f'{name}: {run.robots} robots drawn from its spread, {of_day} (seed {seed}); '
             f'{run.robots - run.not_struck} struck']
    metrics = list(DESIGN_METRICS)
    lines.append('quantile' + ''.join(f'{DESIGN_METRICS[m][0]:>13s}' for m in metrics))
    lines.append('        ' + ''.join(f'{"(" + DESIGN_METRICS[m][2] + ")":>13s}' for m in metrics))
    for level in table[metrics[0]]:
        lines.append(f'{level:8s}' + ''.join(f'{table[m][level]:13.5g}' for m in metrics))
    lines += [f'  {short}: {label} ({metric})' for metric, (short, label, _)
              in DESIGN_METRICS.items()]
    for reason in run.reasons:
        lines.append(f'not struck: {reason}')
    return '\n'.join(lines)


def run_scenes(args) -> int:
    for name, path in available_scenes().items():
        scene = load_scene(str(path))
        print(f'{name:22s} {" ".join(scene.description.split())}')
        print(f'{"":22s} effects: {", ".join(sorted(scene.effects)) or "(none)"}')
    print('\neffects a scene may enable:')
    for name, doc in EFFECTS.items():
        print(f'  {name:20s} {doc}')
    if args.params:
        print('\nparameters (section.key  default  unit  meaning):')
        for section in SECTIONS:
            for key, default, unit, doc in describe(section):
                print(f'  {key:42s} {default!s:>10s} {unit:12s} {doc}')
    return 0


def run_bench(args) -> int:
    from mantis_sim.studies.design import benchmark
    scenes = args.scene or ['reference_air_23mm', 'reference_water_23mm']
    tables = {}
    for name in scenes:
        print(f'# {name}: converged reference ...', file=sys.stderr, flush=True)
        tables[name] = benchmark.accuracy_table(name, repeats=args.repeats)
        print(benchmark.format_table(tables[name], markdown=args.markdown))
        print()
    if args.plot:
        benchmark.plot_tables(tables, args.plot)
        print(f'plot: {args.plot}')
    return 0
