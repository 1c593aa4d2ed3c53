"""The tracker against known truth: rendered strikes tracked, and analysed as `mantis analyze`
analyses a tracker CSV (issue 47, "Known truth").

For each scene and rate: the strike filmed by the simulated camera (`film_strike`, a raw
`.avi`, with a stretch of loading at rest before it), tracked as `mantis track` tracks it
(`open_recording`, `track`, `write_tracks` with the film's calibration.yaml -> tracks.csv),
then tracks.csv and truth.csv analysed alike (`analyse_trial` with the scene's guide distance
and contact angle, as `mantis analyze --d-t-mm ... --contact-angle-deg ...`). Per case:

- found: the share of the frames outside the strike in which every marker is found and named
  right (its position nearer its own truth than any other marker's); the strike: from the
  truth's unlatching (start of phase II) less a frame to its peak tip speed plus 5 ms;
- rest error: each marker's RMS centre error (px, against truth.csv) over the frames at rest
  (more than 2 ms before the unlatching);
- tip speed: the peak tip speed of tracks.csv against that of truth.csv (%).

And one case with markers hidden (`CameraSetup.hidden`, a dark patch over them) in some
frames at rest: their gaps must be exactly there.

    .venv/bin/python bench/bench_tracking_truth.py [--scenes air_19mm ...] [--rates 2000 ...]
        [--before-s 0.25] [--after-s 0.03] [--no-hidden] [--keep DIR] [--write]

--write puts the table in docs/tracking_video.md under "## Measured accuracy".
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
import re
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mantis_rig.analysis.inputs import read_trial  # noqa: E402
from mantis_rig.analysis.one_trial import analyse_trial  # noqa: E402
from mantis_rig.video.recording import open_recording  # noqa: E402
from mantis_rig.video.track import track, write_tracks  # noqa: E402
from mantis_sim.camera.calibration import load_calibration  # noqa: E402
from mantis_sim.camera.render import CameraSetup, film_strike  # noqa: E402
from mantis_sim.scene import load_scene  # noqa: E402

SCENES = ('air_19mm', 'air_23mm', 'water_23mm')
RATES_HZ = (2000.0, 8000.0, 19000.0)
STRIKE_AFTER_PEAK_S = 5e-3
REST_BEFORE_UNLATCH_S = 2e-3
DOC = Path(__file__).resolve().parents[1] / 'docs' / 'tracking_video.md'
HEADING = '## Measured accuracy'
# The targets.
FOUND_TARGET = 0.99
REST_TARGET_PX = 0.1
SPEED_TARGET_PCT = 2.0


@dataclass
class Case:
    scene: str
    rate_hz: float
    frames: int = 0
    strike_frames: int = 0
    found_share: float = float('nan')
    rest_rms_px: dict = field(default_factory=dict)
    truth_speed_mps: float = float('nan')
    tracked_speed_mps: float = float('nan')
    hidden_frames: int = 0
    hidden_gaps: int = 0              # hidden frames the tracker left a gap in
    other_gaps: int = 0               # gaps of the hidden markers outside their hidden frames
    other_gaps_where: str = ''
    missed: str = ''                  # outside the strike: marker -> frames not found/named
    strike_gaps: dict = field(default_factory=dict)   # marker -> gaps in the strike (frames)
    after_hidden: str = ''            # error (px) in the first frame after each hidden stretch
    render_s: float = 0.0
    track_s: float = 0.0
    note: str = ''

    @property
    def speed_error_pct(self) -> float:
        return 100.0 * (self.tracked_speed_mps / self.truth_speed_mps - 1.0)


def run_case(scene_name: str, rate_hz: float, work: Path, before_s: float, after_s: float,
             hidden: tuple = ()) -> Case:
    scene = load_scene(scene_name)
    case = Case(scene_name, rate_hz)
    out = work / f'{scene_name}_{rate_hz:g}' / ('hidden' if hidden else 'plain')
    t0 = time.perf_counter()
    film = film_strike(scene, out, CameraSetup(rate_hz=rate_hz, hidden=hidden),
                       before_s=before_s, after_s=after_s, video_format='avi-raw')
    t1 = time.perf_counter()
    calibration = load_calibration(film.calibration)
    with open_recording(film.video, rate_hz=rate_hz) as recording:
        tracks = track(recording, calibration)
    write_tracks(tracks, out / 'tracks.csv', calibration)
    case.render_s, case.track_s = t1 - t0, time.perf_counter() - t1
    given = {'d_t_mm': scene.geometry.d_t_mm,
             'contact_angle_deg': scene.geometry.contact_angle_deg}
    truth_trial = read_trial(film.truth)
    truth_analysis, _, _ = analyse_trial(truth_trial, given)
    case.truth_speed_mps = truth_analysis.peak_tip_speed
    try:
        tracked_analysis, notes, _ = analyse_trial(read_trial(out / 'tracks.csv'), given)
        case.tracked_speed_mps = tracked_analysis.peak_tip_speed
        case.note = '; '.join(notes)
    except Exception as exc:          # noqa: BLE001 - a refusal is a result here
        case.note = f'tracks.csv refused: {exc}'

    # Truth and tracks frame by frame (the .avi's frames are 0, 1, ...; the truth's numbered
    # from the trigger: the same frames in the same order).
    truth = truth_trial.tracks
    names = sorted(truth.markers_mm)
    true_px = {n: calibration.mm_to_px(truth.markers_mm[n]) for n in names}
    got_px = {n: tracks.xy_px[n] for n in names}
    case.frames = len(truth.frames)
    assert len(tracks.index) == case.frames, (len(tracks.index), case.frames)
    summary = truth_analysis.summary()
    unlatch_s, peak_s = summary['phase_start_s']['II'], summary['peak_tip_speed_s']
    time_s = truth.time_s
    strike = (time_s >= unlatch_s - 1.0 / rate_hz) & (time_s <= peak_s + STRIKE_AFTER_PEAK_S)
    rest = time_s < unlatch_s - REST_BEFORE_UNLATCH_S
    case.strike_frames = int(strike.sum())
    stacked_true = np.stack([true_px[n] for n in names])            # (markers, frames, 2)
    hidden_mask = {n: np.zeros(case.frames, bool) for n in names}
    for name, first, last in hidden:
        hidden_mask[name] |= (truth.frames >= first) & (truth.frames <= last)
    named_right = {}
    for i, n in enumerate(names):
        d = np.linalg.norm(stacked_true - got_px[n][None], axis=2)   # to every marker's truth
        own = d[i].copy()
        d[i] = np.inf
        named_right[n] = np.isfinite(own) & (own < d.min(axis=0))
        err = got_px[n] - true_px[n]
        at_rest = rest & np.isfinite(err[:, 0]) & ~hidden_mask[n]
        case.rest_rms_px[n] = float(np.sqrt(np.mean(np.sum(err[at_rest] ** 2, axis=1))))
    outside = ~strike & ~np.any(np.stack(list(hidden_mask.values())), axis=0)
    all_right = np.all(np.stack([named_right[n] for n in names]), axis=0)
    case.found_share = float(np.mean(all_right[outside]))
    missed = []
    for n in names:
        bad = truth.frames[outside & ~named_right[n]]
        if len(bad):
            missed.append(f'{n}: {len(bad)} ({_ranges(bad)})')
    case.missed = '; '.join(missed)
    case.strike_gaps = {n: int((strike & ~np.isfinite(got_px[n][:, 0])).sum()) for n in names}
    if hidden:
        for n in {h[0] for h in hidden}:
            gap = ~np.isfinite(got_px[n][:, 0])
            case.hidden_frames += int(hidden_mask[n].sum())
            case.hidden_gaps += int((gap & hidden_mask[n]).sum())
            extra = gap & ~hidden_mask[n] & ~strike
            case.other_gaps += int(extra.sum())
            if extra.any():
                case.other_gaps_where += f'{n}: {_ranges(truth.frames[extra])} '
        after = []
        for n, _, last in hidden:
            k = int(np.searchsorted(truth.frames, last + 1))
            if k < case.frames:
                after.append(f'{n} {np.hypot(*(got_px[n][k] - true_px[n][k])):.2f} px '
                             f'(frame {last + 1})')
        case.after_hidden = ', '.join(after)
    return case


def _gaps(case: Case) -> str:
    text = ', '.join(f'{n} {k}' for n, k in sorted(case.strike_gaps.items()) if k)
    return text or 'none'


def _ranges(frames: np.ndarray, most: int = 6) -> str:
    """Frame numbers as runs: '-500..-498, -20'."""
    runs, start, prev = [], None, None
    for f in map(int, frames):
        if start is None:
            start = prev = f
        elif f == prev + 1:
            prev = f
        else:
            runs.append((start, prev))
            start = prev = f
    if start is not None:
        runs.append((start, prev))
    text = [f'{a}..{b}' if b > a else f'{a}' for a, b in runs[:most]]
    return ', '.join(text) + (f', ... ({len(runs)} runs)' if len(runs) > most else '')


def hidden_frames_for(rate_hz: float, before_s: float) -> tuple:
    """Frames to hide markers in, at rest: ma2 for 2 ms from 60 % of the way before the
    trigger, mb1 for 1 ms from 30 % of the way."""
    def frame(t_s):
        return int(round(t_s * rate_hz))
    a = frame(-0.6 * before_s)
    b = frame(-0.3 * before_s)
    return (('ma2', a, a + max(2, frame(2e-3)) - 1), ('mb1', b, b + max(1, frame(1e-3)) - 1))


def table(cases: list[Case], hidden_case: Case | None) -> str:
    names = sorted(cases[0].rest_rms_px) if cases else []
    lines = ['| scene | rate (frames/s) | frames (in the strike) | all markers found and named '
             'outside the strike (%) | ' + ' | '.join(f'{n} rest error (px RMS)' for n in names)
             + ' | gaps in the strike (frames) | peak tip speed, truth (m/s) | tracked (m/s) | '
             'tracked vs truth (%) |',
             '|---|---|---|---|' + '---|' * len(names) + '---|---|---|---|']
    for c in cases:
        lines.append(
            f'| {c.scene} | {c.rate_hz:,.0f} | {c.frames} ({c.strike_frames}) | '
            f'{100 * c.found_share:.2f} | '
            + ' | '.join(f'{c.rest_rms_px[n]:.3f}' for n in names)
            + f' | {_gaps(c)} | {c.truth_speed_mps:.2f} | {c.tracked_speed_mps:.2f} | '
            f'{c.speed_error_pct:+.2f} |')
    out = '\n'.join(lines)
    misses = [f'- {c.scene} at {c.rate_hz:,.0f}/s, frames not found or named right outside '
              f'the strike: {c.missed}' for c in cases if c.missed]
    notes = [f'- {c.scene} at {c.rate_hz:,.0f}/s: {c.note}' for c in cases if c.note]
    if misses or notes:
        out += '\n\n' + '\n'.join(misses + notes)
    if hidden_case is not None:
        h = hidden_case
        out += (f'\n\nHidden markers ({h.scene} at {h.rate_hz:,.0f} frames/s, a dark patch over '
                f'them at rest): {h.hidden_gaps} of {h.hidden_frames} hidden frames are gaps; '
                f'{h.other_gaps} gaps of those markers elsewhere outside the strike'
                + (f' ({h.other_gaps_where.strip()})' if h.other_gaps else '')
                + '; rest error (px RMS) ' + ', '.join(f'{n} {e:.3f}' for n, e in
                                                       sorted(h.rest_rms_px.items()))
                + f'; in the first frame after each hidden stretch: {h.after_hidden}'
                + f'; all markers found and named in {100 * h.found_share:.2f} % of the other '
                f'frames outside the strike; peak tip speed {h.speed_error_pct:+.2f} % '
                f'against truth' + (f' ({h.note})' if h.note else '') + '.')
    met = [c for c in cases if c.found_share >= FOUND_TARGET
           and max(c.rest_rms_px.values()) <= REST_TARGET_PX
           and abs(c.speed_error_pct) <= SPEED_TARGET_PCT]
    out += (f'\n\nTargets (found >= {100 * FOUND_TARGET:g} %, rest error <= {REST_TARGET_PX} '
            f'px RMS, tip speed within {SPEED_TARGET_PCT:g} %): {len(met)} of {len(cases)} '
            'cases meet all three.')
    return out


def _wrapped(text: str, width: int = 96) -> str:
    """Paragraphs and list items wrapped; table rows kept whole."""
    import textwrap
    out = []
    for block in text.split('\n\n'):
        lines = block.split('\n')
        if lines[0].startswith('|'):
            out.append(block)
        else:
            out.append('\n'.join(textwrap.fill(line, width, subsequent_indent='  '
                                                if line.startswith('- ') else '')
                                  for line in lines))
    return '\n\n'.join(out)


def write_doc(text: str) -> None:
    from machine import stamp
    doc = DOC.read_text(encoding='utf-8')
    intro = (f'Known truth: `bench/bench_tracking_truth.py` ({stamp()}). Each strike filmed '
             'as a raw `.avi` (loading at rest before it), tracked as `mantis track` tracks it '
             'and analysed as `mantis analyze` analyses a tracker CSV, beside the same analysis '
             'of its `truth.csv`.')
    section = f'{HEADING}\n\n' + _wrapped(intro + '\n\n' + text) + '\n'
    pattern = re.compile(rf'^{re.escape(HEADING)}\n.*?(?=^## |\Z)', re.S | re.M)
    doc = pattern.sub(section + '\n', doc) if pattern.search(doc) else (
        doc.rstrip('\n') + '\n\n' + section)
    DOC.write_text(doc.rstrip('\n') + '\n', encoding='utf-8')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scenes', nargs='+', default=list(SCENES))
    ap.add_argument('--rates', nargs='+', type=float, default=list(RATES_HZ))
    ap.add_argument('--before-s', type=float, default=0.25,
                    help='loading filmed before the release (s)')
    ap.add_argument('--after-s', type=float, default=0.03, help='filmed after it (s)')
    ap.add_argument('--no-hidden', action='store_true', help='leave out the hidden-marker case')
    ap.add_argument('--hidden-scene', default='air_23mm')
    ap.add_argument('--hidden-rate', type=float, default=8000.0)
    ap.add_argument('--keep', type=Path, help='keep the films and tracks here')
    ap.add_argument('--write', action='store_true', help=f'write the table into {DOC.name}')
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        cases = []
        for scene in args.scenes:
            for rate in args.rates:
                c = run_case(scene, rate, work, args.before_s, args.after_s)
                cases.append(c)
                print(f'{scene} {rate:g}/s: {c.frames} frames, found {100 * c.found_share:.2f} '
                      f'%, rest {max(c.rest_rms_px.values()):.3f} px, speed '
                      f'{c.speed_error_pct:+.2f} % (render {c.render_s:.0f} s, track '
                      f'{c.track_s:.0f} s) {c.missed} {c.note}', flush=True)
        hidden_case = None
        if not args.no_hidden:
            hidden = hidden_frames_for(args.hidden_rate, args.before_s)
            hidden_case = run_case(args.hidden_scene, args.hidden_rate, work, args.before_s,
                                   args.after_s, hidden)
    text = table(cases, hidden_case)
    print('\n' + text)
    if args.write:
        write_doc(text)
        print(f'\nwritten to {DOC}')


if __name__ == '__main__':
    main()
