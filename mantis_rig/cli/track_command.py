"""`mantis track`: a recording (a .cine, an .avi, a folder of frames, one picture) -> the
tracker's CSV form, with no hand tracking (docs/tracking_video.md)."""
from __future__ import annotations

from pathlib import Path

from mantis_rig.cli.options import err, positive_float
from mantis_sim.errors import InputError


def add_video_options(parser) -> None:
    """What tracking a recording takes besides the recording: shared with `analyze` and
    `study attach`."""
    parser.add_argument('--calibration', type=Path, metavar='CAL.yaml',
                        help='pixels to millimetres (scale, origin, tilt, handedness: '
                             'docs/tracking_video.md); default: calibration.yaml beside the '
                             'recording, else image pixels')
    parser.add_argument('--rate', type=positive_float, metavar='FRAMES_PER_S',
                        help='the recording\'s frame rate, for an .avi or a folder of frames '
                             '(default: a .cine beside it, else the trial\'s name, e.g. '
                             '19kfps); a .cine states its own')
    parser.add_argument('--name', action='append', default=[], metavar='NAME=X,Y',
                        help='name a marker on the first frame by hand (pixels), e.g. '
                             'mb1=120.5,340; repeatable; default: named from the linkage')
    parser.add_argument('--marker-distance', metavar='A,B=MM',
                        help='the scale from two markers\' known distance, e.g. mb1,mb2=10.3 '
                             '(instead of a calibration)')


def track_video(args, video, out, label: str = 'track', damage_ok: bool = False):
    """Track ``video`` into ``out`` as the options say. Damage part-way: the frames before it
    are written, then it is an InputError (exit 2), or with ``damage_ok`` a warning (the
    result's ``damage``)."""
    from mantis_rig.video.naming import parse_name_args
    from mantis_rig.video.to_csv import ProgressLine, track_to_csv

    names = parse_name_args(args.name) if args.name else None
    result = track_to_csv(video, out, args.calibration, args.rate, names,
                          args.marker_distance, ProgressLine(label))
    rate = (f'{result.rate_hz:g} frames/s from {result.rate_source}' if result.rate_hz
            else 'unknown (times are frame numbers)')
    err(label, f'{video}: rate {rate}; calibration {result.calibration_source}')
    for name, frame in sorted(result.tracks.lost.items()):
        err(label, f'warning: {name} lost for good after frame {frame}')
    if result.damage and damage_ok:
        err(label, f'warning: {result.damage}; using the {len(result.tracks.index)} frames '
                   'tracked before it')
    elif result.damage:
        raise InputError(f'{result.damage}; the {len(result.tracks.index)} frames tracked '
                         f'before it are kept in {out}')
    return result


def run_track(args) -> int:
    if Path(args.out).is_dir():
        raise InputError(f'--out {args.out} is a directory: name the CSV file to write')
    if not Path(args.out).resolve().parent.is_dir():
        raise InputError(f'--out {args.out}: no such directory {Path(args.out).parent}')
    result = track_video(args, args.input, args.out)
    shares = result.tracks.found_share()
    print(f'{args.out}: {len(result.tracks.index)} frames, markers '
          + ', '.join(f'{n} {100 * shares[n]:.1f} %' for n in result.tracks.names)
          + f' found; {"millimetres" if result.calibration else "image pixels"}')
    if args.plot:
        from mantis_rig.video.plot import plot_tracks
        plot_tracks(args.input, result.tracks, args.plot, args.rate)
    return 0


def add_commands(commands) -> None:
    cmd = commands.add_parser(
        'track', help='a recording -> the tracker\'s CSV (markers found, named and followed)',
        description='Find the markers on the first frame of a recording (a Phantom .cine, an '
                    '.avi, a folder of TIFF or PNG frames, or one picture), name them mb... '
                    '(body) and ma... (arm) from the linkage, follow them to its end and write '
                    'the tracker\'s CSV form: millimetres with a calibration, image pixels '
                    '(x right, y down, 0 at the top-left pixel\'s centre) without. A marker not '
                    'found in a frame is a gap. A damaged recording: the frames before the '
                    'damage are written, then exit 2 naming the frame.')
    cmd.add_argument('input', type=Path, metavar='RECORDING')
    cmd.add_argument('--out', required=True, type=Path, metavar='TRACKS.csv')
    add_video_options(cmd)
    cmd.add_argument('--plot', metavar='FILE.png',
                     help='the first frame with the markers found and their paths')
    cmd.set_defaults(run=run_track)
