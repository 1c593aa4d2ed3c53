"""Tracking a recording: how fast, and in how much memory, as `mantis track` does it.

The recordings are made here, in a temporary folder: one strike of ``air_23mm_rig`` rendered by
the simulated camera at 19,000 frames/s, 512 x 512, 8-bit (a loading phase, the strike and what
follows), played forwards then backwards (the markers' paths stay continuous) until the
recording is long enough, and written uncompressed as the camera's software writes it: a
``.cine`` (bottom-up rows, time stamps) and an 8-bit DIB ``.avi`` (a grey palette, rows
bottom-up, OpenDML ``AVIX`` continuations past 1 GB). Each case runs in a fresh process:
reading alone (every frame's pixels touched), and tracking end to end (open the recording,
find and name the markers, follow them, write the CSV: what ``mantis track INPUT --out
tracks.csv`` does; that command itself is timed where ``.venv/bin/mantis track`` exists). Wall
and CPU time and the peak resident memory (ru_maxrss) of each process; the median of a few runs.

A second table: the follower alone on the real pictures (``test/data/real_frames``: larger
markers, a screenshot's scale), each moved along a path a sub-pixel step a frame with fresh
noise, so that the speed is not the rendered picture's alone.

    .venv/bin/python bench/bench_tracking.py [--frames 2000 20000] [--runs 3] [--keep DIR]
                                             [--no-real] [--write]

The four recordings take some 11 GB of disk (and of page cache, to be read from memory):
about a minute to write; removed at the end unless --keep.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.machine import stamp  # noqa: E402

SECTION = '## Tracking a recording'
PYTHON = sys.executable
RATE_HZ = 19000.0
SCENE = 'air_23mm_rig'


# ------------------------------------------------------------------------ the recordings
def render_strike(folder: Path) -> list[np.ndarray]:
    """One rendered strike's frames (uint8, 512 x 512): 40 ms of loading, 12 ms after."""
    from mantis_rig.video.recording import open_recording
    from mantis_sim.camera.render import film_strike
    from mantis_sim.scene import load_scene
    result = film_strike(load_scene(SCENE), folder / 'strike', before_s=0.04, after_s=0.012,
                         video_format='avi-raw')
    with open_recording(result.video, RATE_HZ) as rec:
        return [np.ascontiguousarray(f.image) for f in rec.frames()]


def looped(frames: list, n: int):
    """n frames: forwards, backwards, forwards..."""
    period = 2 * len(frames) - 2
    for k in range(n):
        j = k % period
        yield frames[j if j < len(frames) else period - j]


def write_cine(path: Path, frames: list, n: int) -> Path:
    from mantis_sim.camera.cine_writer import CineWriter
    with CineWriter(path, 512, 512, n, RATE_HZ, first_number=-(n // 2)) as w:
        for image in looped(frames, n):
            w.write(image)
    return path


def write_dib_avi(path: Path, frames: list, n: int, riff_bytes: int = 1 << 30) -> Path:
    """An 8-bit DIB .avi as the camera's software writes it: BI_RGB with a grey palette, rows
    bottom-up, '00db' chunks; past ``riff_bytes`` the OpenDML continuations (RIFF AVIX), the
    total frame count in the odml list's dmlh. (No idx1 or super index: the reader walks
    the chunks.)"""
    h, w = frames[0].shape
    stride = (w + 3) & ~3
    image_bytes = stride * h

    def chunk(fourcc, body):
        return fourcc + struct.pack('<I', len(body)) + body + b'\0' * (len(body) & 1)

    def lst(kind, body):
        return chunk(b'LIST', kind + body)
    palette = np.column_stack([np.arange(256)] * 3 + [np.zeros(256, int)]).astype(np.uint8)
    strf = struct.pack('<IiiHHIIiiII', 40, w, h, 1, 8, 0, image_bytes, 0, 0, 256, 0)
    strf += palette.tobytes()
    per_riff = max(1, (riff_bytes - 4096) // (image_bytes + 8))
    in_first = min(n, per_riff)
    avih = struct.pack('<14I', 33333, 0, 0, 0x10, in_first, 0, 1, 0, w, h, 0, 0, 0, 0)
    strh = b'vids' + b'\0' * 4 + struct.pack('<IHHIIIIIIIIhhhh', 0, 0, 0, 0, 1, 30, 0,
                                             in_first, 0, 0, 0, 0, 0, w, h)
    hdrl = lst(b'hdrl', chunk(b'avih', avih)
               + lst(b'strl', chunk(b'strh', strh) + chunk(b'strf', strf))
               + lst(b'odml', chunk(b'dmlh', struct.pack('<I', n) + b'\0' * 244)))
    source = looped(frames, n)
    padded = np.zeros((h, stride), np.uint8)
    with open(path, 'wb') as f:
        done, first = 0, True
        while done < n:
            count = min(n - done, per_riff)
            movi_bytes = 4 + count * (8 + image_bytes)
            head = b'AVI ' + hdrl if first else b'AVIX'
            f.write(b'RIFF' + struct.pack('<I', len(head) + 8 + movi_bytes) + head)
            f.write(b'LIST' + struct.pack('<I', movi_bytes) + b'movi')
            tag = b'00db' + struct.pack('<I', image_bytes)
            for _ in range(count):
                padded[:, :w] = next(source)[::-1]
                f.write(tag)
                f.write(padded.data)
            done += count
            first = False
    return path


# --------------------------------------------------------------------- the measurements
READ_ONLY = '''
import sys, time
from mantis_rig.video.recording import open_recording
total = 0
start = time.perf_counter()
with open_recording(sys.argv[1], float(sys.argv[2])) as rec:
    for frame in rec.frames():
        total += int(frame.image[::64, ::64].sum())   # every page of every frame reached
print(time.perf_counter() - start)
'''

TRACK = '''
import sys
from mantis_rig.video.recording import open_recording
from mantis_rig.video.track import track, write_tracks
with open_recording(sys.argv[1], float(sys.argv[2])) as rec:
    tracks = track(rec)
write_tracks(tracks, sys.argv[3])
'''


def mantis_track() -> list[str] | None:
    """`mantis track`, where it exists."""
    exe = REPO / '.venv' / 'bin' / 'mantis'
    if not exe.exists():
        return None
    probe = subprocess.run([str(exe), 'track', '--help'], capture_output=True, text=True,
                           check=False)
    return [str(exe), 'track'] if probe.returncode == 0 else None


def run_child(argv: list[str]) -> dict:
    """Wall and CPU seconds and peak RSS (MB) of one fresh process."""
    code = ('import json, resource, subprocess, sys, time\n'
            't = time.perf_counter()\n'
            'p = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n'
            'wall = time.perf_counter() - t\n'
            'u = resource.getrusage(resource.RUSAGE_CHILDREN)\n'
            'print(json.dumps(dict(rc=p.returncode, err=p.stderr[-2000:], '
            'out=p.stdout[-200:], wall=wall, cpu=u.ru_utime + u.ru_stime, '
            'rss_mb=u.ru_maxrss / 1024)))\n')
    # A fresh parent for each: RUSAGE_CHILDREN is then this one child's.
    out = subprocess.run([PYTHON, '-c', code, *argv], capture_output=True, text=True,
                         check=True, cwd=REPO,
                         env={**os.environ, 'PYTHONPATH': str(REPO)}).stdout
    result = json.loads(out)
    if result['rc'] != 0:
        raise RuntimeError(f'{argv}: failed:\n{result["err"]}')
    return result


def median_of(runs: list[dict], loop: bool = False) -> dict:
    out = {k: float(np.median([r[k] for r in runs])) for k in ('wall', 'cpu', 'rss_mb')}
    if loop:        # the reading loop's own seconds, as the child printed them
        out['loop'] = float(np.median([float(r['out'].split()[-1]) for r in runs]))
    return out


def measure(path: Path, frames: int, runs: int, out_dir: Path, command) -> dict:
    rate = f'{RATE_HZ:g}'
    csv = out_dir / f'{path.stem}.csv'
    read = median_of([run_child([PYTHON, '-c', READ_ONLY, str(path), rate])
                      for _ in range(runs)], loop=True)
    if command:
        argv = [*command, str(path), '--out', str(csv), '--rate', rate]
        if path.suffix == '.cine':
            argv = argv[:-2]
    else:
        argv = [PYTHON, '-c', TRACK, str(path), rate, str(csv)]
    tracked = median_of([run_child(argv) for _ in range(runs)])
    rows = sum(1 for _ in open(csv, encoding='utf-8'))
    return dict(frames=frames, read=read, track=tracked, csv_rows=rows)


def real_pictures(frames: int = 1000) -> list[dict]:
    """The follower alone on each real picture moved along a path with fresh noise."""
    import cv2

    from mantis_rig.video.follow import Follower
    from mantis_rig.video.recording import open_recording
    from mantis_rig.video.track import name_first_frame
    rows = []
    rng = np.random.default_rng(0)
    for path in sorted((REPO / 'test' / 'data' / 'real_frames').glob('*.png')):
        with open_recording(path) as rec:
            grey = next(iter(rec.frames())).image.astype(np.float32)
        h, w = grey.shape
        noise = rng.normal(0, 1.5, (16, h, w)).astype(np.float32)
        shifts = np.column_stack([2 * np.sin(np.arange(frames) / 50.0),
                                  1.5 * np.cos(np.arange(frames) / 70.0)])
        pictures = []
        for k in range(64):      # 64 distinct pictures, reused in order along the path
            m = np.float32([[1, 0, shifts[k, 0]], [0, 1, shifts[k, 1]]])
            moved = cv2.warpAffine(grey, m, (w, h), flags=cv2.INTER_LINEAR,
                                   borderMode=cv2.BORDER_REPLICATE)
            pictures.append(np.clip(moved + noise[k % 16], 0, 255).astype(np.uint8))
        seq = [pictures[j if j < 64 else 127 - j] for j in (np.arange(frames) % 128)]
        try:
            naming = name_first_frame(seq[0])
        except Exception as exc:  # noqa: BLE001 - a picture the naming refuses: say so
            rows.append(dict(name=path.stem, markers=0, fps=float('nan'), gaps=str(exc)[:40]))
            continue
        t = time.perf_counter()
        follower = Follower(seq[0], naming, 0)
        gaps = 0
        for k, image in enumerate(seq[1:], start=1):
            gaps += int(np.isnan(follower.step(image, k)[:, 0]).sum())
        fps = (frames - 1) / (time.perf_counter() - t)
        rows.append(dict(name=path.stem, markers=len(follower.names), fps=fps, gaps=gaps,
                         size=f'{w}x{h}'))
    return rows


# ----------------------------------------------------------------------------- output
def table(results: list[dict]) -> str:
    lines = ['| recording | frames | size on disk | reading alone: frames/s | tracked end to '
             'end: wall s | frames/s | CPU s | peak RSS MB (reading) | peak RSS MB '
             '(tracking) |', '|---|---|---|---|---|---|---|---|---|']
    for r in results:
        rd, tr = r['read'], r['track']
        lines.append(f'| {r["kind"]} | {r["frames"]:,} | {r["gb"]:.2f} GB | '
                     f'{r["frames"] / rd["loop"]:,.0f} | {tr["wall"]:.2f} | '
                     f'{r["frames"] / tr["wall"]:,.0f} | {tr["cpu"]:.2f} | '
                     f'{rd["rss_mb"]:.0f} | {tr["rss_mb"]:.0f} |')
    return '\n'.join(lines)


def real_table(rows: list[dict]) -> str:
    lines = ['| real picture | size | markers | follower frames/s | gaps (marker-frames) |',
             '|---|---|---|---|---|']
    for r in rows:
        lines.append(f'| {r["name"]} | {r.get("size", "")} | {r["markers"]} | '
                     f'{r["fps"]:,.0f} | {r["gaps"]} |')
    fps = [r['fps'] for r in rows if np.isfinite(r['fps'])]
    if fps:
        lines.append(f'| **median of {len(fps)}** | | | **{np.median(fps):,.0f}** | |')
    return '\n'.join(lines)


def write_doc(text: str) -> None:
    path = REPO / 'docs' / 'performance.md'
    doc = path.read_text(encoding='utf-8')
    pattern = re.compile(rf'{re.escape(SECTION)}\n.*?(?=\n## |\Z)', re.S)
    doc = pattern.sub(lambda _: text.rstrip('\n'), doc) if pattern.search(doc) \
        else doc.rstrip('\n') + '\n\n' + text.rstrip('\n') + '\n'
    path.write_text(doc, encoding='utf-8')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--frames', type=int, nargs='+', default=[2000, 20000])
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--formats', nargs='+', default=['cine', 'avi'], choices=['cine', 'avi'])
    ap.add_argument('--no-real', action='store_true', help='skip the real pictures table')
    ap.add_argument('--real-frames', type=int, default=1000)
    ap.add_argument('--keep', type=Path, default=None,
                    help='make the recordings in this folder and keep them (reused if there)')
    ap.add_argument('--write', action='store_true', help='put the tables in docs/performance.md')
    args = ap.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix='bench_tracking_'))
    folder.mkdir(parents=True, exist_ok=True)
    command = mantis_track()
    print(f'recordings in {folder}; timing '
          f'{"`mantis track`" if command else "open_recording + track + write_tracks"}')
    results = []
    try:
        frames = None
        for n in args.frames:
            for kind in args.formats:
                path = folder / f'strike_{n}.{kind}'
                if not path.exists():
                    if frames is None:
                        t = time.perf_counter()
                        frames = render_strike(folder)
                        print(f'rendered {len(frames)} frames in {time.perf_counter() - t:.1f} s')
                    t = time.perf_counter()
                    (write_cine if kind == 'cine' else write_dib_avi)(path, frames, n)
                    print(f'wrote {path.name} in {time.perf_counter() - t:.1f} s')
                r = measure(path, n, args.runs, folder, command)
                r.update(kind=f'.{kind}' if kind == 'cine' else 'raw .avi (DIB)',
                         gb=path.stat().st_size / 1e9)
                results.append(r)
                print(f'{path.name}: read {n / r["read"]["loop"]:,.0f} frames/s, tracked '
                      f'{r["track"]["wall"]:.2f} s ({n / r["track"]["wall"]:,.0f} frames/s, '
                      f'CPU {r["track"]["cpu"]:.2f} s), peak RSS {r["track"]["rss_mb"]:.0f} MB'
                      f' ({r["csv_rows"]} CSV lines)', flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    main_table = table(results)
    print('\n' + main_table)
    real = None if args.no_real else real_table(real_pictures(args.real_frames))
    if real:
        print('\n' + real)
    if args.write:
        how = ('`mantis track INPUT --out tracks.csv`' if command else
               'open_recording, track and write_tracks to a CSV (what `mantis track` does)')
        text = (f'{SECTION}\n\nWritten by `bench/bench_tracking.py --write`: recordings of one '
                f'rendered strike of `{SCENE}` (19,000 frames/s, 512 x 512, 8-bit; 5 markers) '
                'played forwards and backwards to length, written uncompressed as the camera\'s '
                'software writes them (`.cine`; 8-bit DIB `.avi`, bottom-up rows, OpenDML past '
                '1 GB), read from the page cache (a file on disk only reads at the disk\'s '
                'speed: here near 500 MB/s, 1,900 frames/s). Each figure the median of '
                f'{args.runs} fresh processes. "Reading alone": every frame delivered and each of '
                'its pages reached (the loop\'s own time); "tracked end to end": the whole '
                f'process of {how}, start-up, imports and naming included; '
                'peak RSS: the process\'s maximum resident memory (ru_maxrss). '
                f'{stamp()}.\n\n{main_table}\n')
        if real:
            text += ('\nThe follower alone (frames in memory) on each real picture of '
                     '`test/data/real_frames` (a screenshot\'s scale: markers some 25 px '
                     f'across), moved along a sub-pixel path with fresh noise, '
                     f'{args.real_frames:,} frames:\n\n{real}\n\nWhere markers are lost (gaps: '
                     'these screenshots moved and made noisy lose some), the follower looks for '
                     'them again within their link\'s reach of the frame every few frames, then '
                     'less often (up to every 256): those searches (`find_markers`, tens of '
                     'milliseconds each on these pictures), not the following, make the slow '
                     'rows.\n')
        write_doc(text)
        print('written to docs/performance.md')


if __name__ == '__main__':
    main()
