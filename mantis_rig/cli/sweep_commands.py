"""`mantis sweep` and `mantis sweep-plot`: design studies over many simulated strikes."""
from __future__ import annotations

from pathlib import Path
import sys

from mantis_rig.cli.options import add_cluster_options, check_spread_request


def add_commands(commands) -> None:
    sweep = commands.add_parser(
        'sweep', help='simulate many designs of a scene into a Parquet table',
        description='Vary scene parameters over a grid (--vary KEY=LO:HI:N, repeatable) or a '
                    'Latin hypercube (--vary KEY=LO:HI ... --sample N) and simulate every '
                    'design, on a local Dask cluster (default), an existing one (--scheduler) '
                    'or this process (--workers 0). A rerun with the same --out computes only '
                    'the designs the table lacks.')
    sweep.add_argument('--scene', required=True, help='scene name or YAML path')
    sweep.add_argument('--set', dest='overrides', action='append', default=[],
                       metavar='KEY=VALUE', help='a fixed scene parameter for every design')
    sweep.add_argument('--vary', action='append', default=[], required=True,
                       metavar='KEY=LO:HI[:N]', help='a varied parameter and its range')
    sweep.add_argument('--sample', type=int, metavar='N',
                       help='N designs from a Latin hypercube over the ranges (else a grid)')
    sweep.add_argument('--seed', type=int, default=0, help='seed of the Latin hypercube')
    sweep.add_argument('--accuracy', type=float, metavar='REL',
                       help='the loosest tolerance of the fast path whose peak tip speed and '
                       'spring energy are within REL (relative) of the converged ones on a '
                       'sample of the designs, with a margin of 3')
    sweep.add_argument('--solver', help='integrator (instead of --accuracy)')
    sweep.add_argument('--rtol', type=float, help='relative tolerance (instead of --accuracy)')
    sweep.add_argument('--out', type=Path, required=True, help='results table (.parquet)')
    add_cluster_options(sweep)
    sweep.add_argument('--spread', type=int, default=0, metavar='N',
                       help='also draw N robots of each design from the scene\'s spread and '
                            'add the quantiles q05..q95 of tip speed, spring energy and tendon '
                            'force as columns (docs/spread.md); the same robots for every design')
    sweep.add_argument('--spread-seed', type=int, default=1,
                       help='seed of the robots drawn by --spread (default 1)')
    sweep.add_argument('--chunk-size', type=int, help='designs per task (default: by cost)')
    sweep.add_argument('--quiet', action='store_true', help='no progress bar')
    sweep.set_defaults(run=run_sweep_command)

    plot = commands.add_parser(
        'sweep-plot', help='figures of a sweep: heat maps, Pareto front, best designs',
        description='Heat maps of a metric over two varied keys, the Pareto front of tip speed '
                    'against peak tendon force and stored energy, and a table of the best '
                    'designs under a force limit.')
    plot.add_argument('table', type=Path, help='a table written by mantis sweep')
    plot.add_argument('--out', type=Path, required=True, help='directory for the figures')
    plot.add_argument('--metric', default='peak_tip_speed_mps', help='heat-map metric')
    plot.add_argument('--force-limit', type=float, default=18.0, metavar='N',
                      help='peak tendon force limit of the best-designs table (default 18 N)')
    plot.add_argument('--top', type=int, default=10, help='rows of the best-designs table')
    plot.set_defaults(run=run_sweep_plot)


def run_sweep_command(args) -> int:
    from mantis_sim.scene import load_scene
    from mantis_sim.studies.design.accuracy import choose_setting
    from mantis_sim.studies.design.designs import check_ranges, grid, latin_hypercube, parse_range
    from mantis_sim.studies.design.sweep import SweepError, run_sweep

    if args.out.suffix != '.parquet':
        raise SweepError(f'--out {args.out}: the table is Parquet: name a .parquet file')
    if not args.out.resolve().parent.is_dir():
        raise SweepError(f'--out {args.out}: no such directory {args.out.parent}')
    if args.accuracy is not None and (args.solver or args.rtol is not None):
        raise SweepError('--accuracy picks the solver and tolerance: give it, or --solver/'
                         '--rtol, not both')
    if args.workers is not None and args.workers < 0:
        raise SweepError(f'--workers {args.workers}: must be >= 0')
    if args.workers is not None and args.scheduler:
        raise SweepError('--workers sizes the local cluster; --scheduler uses an existing one')
    if args.chunk_size is not None and args.chunk_size < 1:
        raise SweepError(f'--chunk-size {args.chunk_size}: must be >= 1')
    ranges = [parse_range(text, need_n=args.sample is None) for text in args.vary]
    overrides = list(args.overrides)
    base = load_scene(args.scene, overrides)          # unknown scene or bad --set: refused
    if args.spread:
        check_spread_request(args.spread, {base.name: base})
    check_ranges(base, ranges)
    estimate_s = 0.01
    designs = (latin_hypercube(ranges, args.sample, args.seed) if args.sample is not None
               else grid(ranges))
    if args.accuracy is not None:
        setting = choose_setting(args.scene, overrides, args.accuracy, designs)
        print(f'mantis sweep: --accuracy {args.accuracy:g}: {setting}', file=sys.stderr)
        overrides += setting.overrides()
        estimate_s = setting.wall_ms * 1e-3
    else:
        if args.solver:
            overrides.append(f'integration.solver={args.solver}')
        if args.rtol is not None:
            overrides.append(f'integration.rtol={args.rtol!r}')
        load_scene(args.scene, overrides)             # a bad solver or tolerance: refused
    summary = run_sweep(args.scene, overrides, designs, args.out, scheduler=args.scheduler,
                        workers=args.workers, chunk_size=args.chunk_size,
                        estimated_strike_s=estimate_s, progress=not args.quiet,
                        spread_robots=args.spread, spread_seed=args.spread_seed)
    print(summary, file=sys.stderr)
    print(f'mantis sweep: table {args.out}', file=sys.stderr)
    return 0


def run_sweep_plot(args) -> int:
    from mantis_sim.studies.design.sweep import read_table
    from mantis_sim.studies.design.sweep_plots import plot_sweep

    if not args.table.exists():
        from mantis_sim.studies.design.sweep import SweepError
        raise SweepError(f'{args.table}: no such file')
    rows = read_table(args.table)
    written = plot_sweep(rows, args.out, metric=args.metric, force_limit_n=args.force_limit,
                         top=args.top)
    for path in written:
        print(path)
        if path.name == 'spread_effects.csv':
            print(_spread_effects_text(path))
    return 0


def _spread_effects_text(path: Path) -> str:
    import csv
    lines = []
    with open(path, encoding='utf-8') as handle:
        for e in csv.DictReader(handle):
            change, sd = float(e['change_of_median']), float(e['one_strike_sd'])
            verdict = ('exceeds' if e['exceeds_one_strike_scatter'] == 'True'
                       else 'is within')
            needed = float(e['strikes_per_design_to_see_it'])
            lines.append(f'  {e["key"]} {float(e["low"]):g} to {float(e["high"]):g}: the median '
                         f'{e["metric"]} changes by {change:+.3g}, which {verdict} one strike\'s '
                         f'scatter (sd {sd:.3g}); a lab sees it with '
                         + ('no number of strikes' if needed == float('inf')
                            else f'{needed:.0f} strikes per design') + ' (80 % power, 5 % level)')
    return '\n'.join(lines)
