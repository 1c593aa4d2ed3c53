"""The marker finder and namer on the real camera frames: each picture read as a one-frame
input, its found and named markers against the lab's first-frame positions.

    .venv/bin/python bench/bench_real_frames.py [FOLDER] [--write]

FOLDER holds `<trial>.png` and `first_frame_markers.csv` (default: test/data/real_frames). The
lab's positions are in the export's calibrated frame and the pictures are screenshots at their
own crop and scale, perhaps mirrored: the two are compared up to a similarity (scale, rotation,
shift, mirror) fitted by least squares on the named pairs. The residual is the RMS misfit as a
share of the RMS distance of the lab's markers from their centroid; a picture passes when every
marker of the lab's first frame is found and named and the residual is at most 5 %. With
--write the table goes into docs/tracking_video.md ("The real frames").
"""
from __future__ import annotations

import csv
from pathlib import Path
import sys
import time

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mantis_rig.video.markers import find_markers, grey_frame  # noqa: E402
from mantis_rig.video.naming import NamingError, name_markers  # noqa: E402

PASS_RESIDUAL = 0.05


def lab_markers(csv_path: Path) -> dict:
    """trial -> {marker: (x, y)} in the export's units (a similarity makes the unit moot)."""
    out: dict = {}
    with open(csv_path, newline='') as f:
        for row in csv.DictReader(f):
            out.setdefault(row['trial'], {})[row['marker']] = (float(row['x']), float(row['y']))
    return out


def similarity_residual(src: np.ndarray, dst: np.ndarray) -> float:
    """RMS misfit of the best similarity (mirror allowed) src -> dst, over dst's RMS spread."""
    z = dst[:, 0] + 1j * dst[:, 1]
    zc = z - z.mean()
    spread = np.sqrt(np.mean(np.abs(zc) ** 2))
    best = np.inf
    for mirror in (False, True):
        w = src[:, 0] + 1j * (-src[:, 1] if mirror else src[:, 1])
        wc = w - w.mean()
        c = np.sum(zc * np.conj(wc)) / np.sum(np.abs(wc) ** 2)
        best = min(best, np.sqrt(np.mean(np.abs(zc - c * wc) ** 2)))
    return float(best / spread)


def judge(png: Path, lab: dict) -> dict:
    grey = grey_frame(cv2.imread(str(png), cv2.IMREAD_UNCHANGED), str(png))
    t0 = time.perf_counter()
    blobs = find_markers(grey, where=png.name)
    try:
        naming = name_markers([(b.x_px, b.y_px) for b in blobs],
                              [b.diameter_px for b in blobs], where=png.name)
        found = naming.positions_px
    except NamingError:
        naming, found = None, {}
    seconds = time.perf_counter() - t0
    common = sorted(set(found) & set(lab))
    residual = (similarity_residual(np.array([found[n] for n in common]),
                                    np.array([lab[n] for n in common]))
                if len(common) >= 3 else float('nan'))
    missing = sorted(set(lab) - set(found))
    ok = not missing and residual <= PASS_RESIDUAL
    return {'trial': png.stem, 'blobs': len(blobs), 'named': ' '.join(sorted(found)),
            'missing': ' '.join(missing), 'residual': residual, 'ok': ok, 'seconds': seconds,
            'layout': naming.layout if naming else '-',
            'mirrored': naming.mirrored if naming else None}


SECTION = '## The real frames'


def main(folder: Path, write: bool = False) -> int:
    lab = lab_markers(folder / 'first_frame_markers.csv')
    rows = [judge(folder / f'{trial}.png', markers) for trial, markers in sorted(lab.items())
            if (folder / f'{trial}.png').exists()]
    passed = sum(r['ok'] for r in rows)
    res = np.array([r['residual'] for r in rows])
    lines = ['| trial | blobs found | markers named | lab markers missing | residual (%) | '
             'passes |', '|---|---|---|---|---|---|']
    for r in rows:
        lines.append(f'| {r["trial"]} | {r["blobs"]} | {r["named"]} | {r["missing"] or "none"} '
                     f'| {100 * r["residual"]:.2f} | {"yes" if r["ok"] else "no"} |')
    summary = (f'{passed} of {len(rows)} pass (every lab marker found and named, residual '
               f'<= {PASS_RESIDUAL:.0%}); residual median {100 * np.nanmedian(res):.2f} %, '
               f'worst {100 * np.nanmax(res):.2f} %.')
    table = '\n'.join(lines) + '\n\n' + summary + '\n'
    print(table)
    if write:
        from bench.machine import stamp
        _write_section(f'`bench/bench_real_frames.py` ({stamp()}). Each picture of '
                       '`test/data/real_frames/` read as a one-frame recording; its markers '
                       'found and named, set against the lab\'s first-frame positions up to a '
                       'similarity (scale, rotation, shift, mirror); the residual is the RMS '
                       'misfit over the RMS distance of the lab\'s markers from their centroid '
                       '(a wrongly named marker costs 20 % or more).\n\n' + table)
    return 0


def _write_section(text: str) -> None:
    from bench.machine import replace_section
    replace_section(ROOT / 'docs' / 'tracking_video.md', SECTION, text)


if __name__ == '__main__':
    args = [a for a in sys.argv[1:] if a != '--write']
    default = ROOT / 'test' / 'data' / 'real_frames'
    sys.exit(main(Path(args[0]) if args else default, write='--write' in sys.argv))
