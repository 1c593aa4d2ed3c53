"""What several commands share: one-line errors, the trial-condition options and the options
for what a tracker export leaves out."""
from __future__ import annotations

import argparse
import math
import re
import sys

from mantis_sim.errors import InputError
from mantis_sim.studies.shared.finite_values import json_safe  # noqa: F401 - the commands'


def err(command, text):
    print(f'mantis {command}: {text}', file=sys.stderr)


def check_out_folder(path) -> None:
    """--out names a folder to write into (made if missing): refuse a file there, before any
    work."""
    if path is not None and path.exists() and not path.is_dir():
        raise InputError(f'--out {path}: exists and is not a folder')


def check_spread_request(robots: int, scenes: dict, per: str = '') -> None:
    """Refuse a ``--spread N`` of fewer than two robots (``per``: what each N is drawn for),
    or for scenes (name -> Scene) without a spread."""
    if robots < 2:
        raise InputError(f'--spread {robots}: a spread needs at least 2 robots{per}')
    missing = sorted(name for name, scene in scenes.items() if scene.spread is None)
    if missing:
        raise InputError(f'--spread: no spread in the scene of {", ".join(missing)}: fit one '
                         f'with `mantis identify --spread` (docs/spread.md)')


# ------------------------------------------------------------- trial conditions, by hand
def add_condition_options(parser) -> None:
    parser.add_argument('--d-t-mm', type=float, metavar='MM',
                        help='tendon guide distance d_t of the trial (default: the bag\'s '
                             'trial conditions, else 23 mm)')
    parser.add_argument('--contact-angle-deg', type=float, metavar='DEG',
                        help='contact angle measured on the rig for this trial; sets θ3\'s '
                             'zero (default: the bag\'s trial conditions, else unknown: θ3 '
                             'counts from the latch)')


# ------------------------------------------------------- what a tracker export leaves out
def add_cluster_options(parser) -> None:
    """--scheduler and --workers: where many simulated strikes run (mantis_sim.studies)."""
    parser.add_argument('--scheduler', metavar='tcp://HOST:PORT',
                        help='an existing Dask scheduler (default: a local cluster)')
    parser.add_argument('--workers', type=int,
                        help='local workers (default: one per core; 0: this process only)')


def positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a number') from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f'{text!r}: must be a positive number')
    return value


def positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a whole number') from None
    if value < 1:
        raise argparse.ArgumentTypeError(f'{text!r}: must be 1 or more')
    return value


#: analysis.inputs.tracker_export.LENGTH_UNITS, written out: building the parser imports no
#: analysis.
LENGTH_UNITS = ('mm', 'um', 'px')


def add_export_options(parser) -> None:
    parser.add_argument('--frame-rate', type=positive_float, metavar='FPS',
                        help='frames per second of a tracker export whose Record Rate is N/A '
                             '(and whose trial name carries none, like "11kfps"); not for bags')
    parser.add_argument('--length-unit', choices=LENGTH_UNITS,
                        help='the unit the export\'s coordinates are really in, overriding its '
                             'Export Units (px: converted by the calibration\'s mm/pixel); '
                             'not for bags')


def export_options(args) -> dict:
    """--frame-rate and --length-unit as load_tracks's keyword arguments."""
    return {'frame_rate_hz': getattr(args, 'frame_rate', None),
            'length_unit': getattr(args, 'length_unit', None)}


def given_conditions(args) -> dict:
    """The trial conditions given as options, checked against their ranges (ConditionError)."""
    from mantis_rig.analysis.bag_conditions import CONDITION_OPTIONS
    from mantis_rig.trial.supervisor_settings import ConditionError, check_value

    given = {}
    for name, option in CONDITION_OPTIONS.items():
        value = getattr(args, name, None)
        if value is not None:
            try:
                check_value(name, value)
            except ConditionError as exc:
                raise ConditionError(f'{option}: {exc}') from None
            given[name] = value
    return given


#: how a rig's stack may be laid out: every node in one process, or the rig apart
PROCESSES = ('single', 'multi')
#: an absolute ROS namespace, such as /rig2
ROS_NAMESPACE = re.compile(r'(/[A-Za-z][A-Za-z0-9_]*)+')


def supervisor_value(key: str, text: str):
    """A supervisor parameter's value from its text on the command line (KEY=VALUE), typed as
    its default is; ConditionError names a value that is not."""
    from mantis_rig.trial.supervisor_settings import PARAMETERS, ConditionError

    default = PARAMETERS[key].default
    if isinstance(default, bool):
        if text.lower() not in ('true', 'false', '1', '0', 'yes', 'no'):
            raise ConditionError(f'{key} = {text!r} is not a boolean')
        return text.lower() in ('true', '1', 'yes')
    if isinstance(default, float):
        try:
            return float(text)
        except ValueError:
            raise ConditionError(f'{key} = {text!r} is not a number') from None
    return text
