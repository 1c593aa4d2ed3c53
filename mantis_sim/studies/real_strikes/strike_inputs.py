"""What `mantis identify`, `compare` and `day-state` start from: the real strikes of a summary
table, with their recorded motion from processed records and tracker exports, the scene of each
group of them, and where they are simulated.

A tracker export is analysed by the rig package's analysis, which this package does not import:
the caller hands that analysis in (`SeriesFromExport`).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from mantis_sim.errors import InputError
from mantis_sim.scene import available_scenes, load_scene
from mantis_sim.studies.shared.parallel import ClusterMap

from .strikes import RealStrike, StrikeDataError, StrikeSeries, read_strikes

#: A tracker export (path) analysed into the motion of the table's strike it records.
SeriesFromExport = Callable[[Path, RealStrike], StrikeSeries]


@dataclass(frozen=True)
class StrikeInputs:
    """The strikes and where they run, as the options name them: ``exports`` 'TRIAL=PATH',
    ``scenes`` 'GROUP=SCENE' (default: a group's scene is its name), ``groups`` the groups
    kept (default all); ``scheduler``/``workers`` as ClusterMap's, ``progress`` its line."""
    strikes: Path
    processed: Optional[Path] = None
    exports: Sequence[str] = ()
    scenes: Sequence[str] = ()
    groups: Sequence[str] = ()
    scheduler: Optional[str] = None
    workers: Optional[int] = None
    progress: bool = True

    def cluster(self) -> ClusterMap:
        """Where the strikes are simulated (a context manager)."""
        return ClusterMap(self.scheduler, self.workers, progress=self.progress)

    def sources(self, exports: bool = False) -> list[str]:
        """The files the strikes came from, for a scene's provenance."""
        return ([str(self.strikes)] + ([str(self.processed)] if self.processed else [])
                + ([text.partition('=')[2] for text in self.exports] if exports else []))


def load_strikes(inputs: StrikeInputs,
                 series_from_export: Optional[SeriesFromExport] = None) -> list[RealStrike]:
    """The table's strikes (of ``inputs.groups`` if given), each export's motion on its
    strike."""
    strikes = read_strikes(inputs.strikes, inputs.processed)
    by_trial = {s.trial: i for i, s in enumerate(strikes)}
    for text in inputs.exports:
        trial, sep, path = text.partition('=')
        if not sep or trial not in by_trial:
            raise StrikeDataError(f'--export {text}: expected TRIAL=PATH with TRIAL a trial of '
                                  f'{inputs.strikes}')
        if series_from_export is None:
            raise InputError(f'--export {text}: no analysis of tracker exports given')
        i = by_trial[trial]
        strikes[i] = strikes[i].with_series(series_from_export(Path(path), strikes[i]), path)
    if inputs.groups:
        unknown = sorted(set(inputs.groups) - {s.group for s in strikes})
        if unknown:
            raise StrikeDataError(f'--group {", ".join(unknown)}: no such strikes in '
                                  f'{inputs.strikes} (groups: '
                                  f'{", ".join(sorted({s.group for s in strikes}))})')
        strikes = [s for s in strikes if s.group in inputs.groups]
    return strikes


def choose_scenes(inputs: StrikeInputs, strikes: list[RealStrike]) -> tuple[dict, dict]:
    """(group -> Scene, group -> scene file path) for every group among the strikes."""
    chosen = {}
    for text in inputs.scenes:
        group, sep, name = text.partition('=')
        if not sep:
            raise InputError(f'--scene {text}: expected GROUP=SCENE')
        chosen[group] = name
    known = available_scenes()
    scenes, paths = {}, {}
    for group in sorted({s.group for s in strikes}):
        name = chosen.get(group, group)
        scenes[group] = load_scene(name)
        paths[group] = Path(name) if Path(name).suffix in ('.yaml', '.yml') else known[name]
    return scenes, paths


def seat_summary(strikes: list[RealStrike]) -> dict:
    """How many strikes have a tracked seat, and which have none."""
    missing = [s.trial for s in strikes if s.seat_deg is None]
    return {'seated': len(strikes) - len(missing), 'without_seat': missing}


def seat_line(seats: dict) -> str:
    return (f'arms latched at their tracked seats ({seats["seated"]} strikes)'
            + (f'; no seat, at the contact angle: {", ".join(seats["without_seat"])}'
               if seats['without_seat'] else ''))
