"""Wall time of loading and analysing the real 3.4 s trial (65,255 frames)."""
from pathlib import Path
import sys
import time

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mantis_rig.analysis import analyze_tracks, load_tracks  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / 'test' / 'data' / \
    'air_23mm_2p3mmps_trial1_markers.csv.gz'


def main() -> None:
    t0 = time.perf_counter()
    tracks = load_tracks(DATA)
    t1 = time.perf_counter()
    analysis = analyze_tracks(tracks)
    t2 = time.perf_counter()
    print(f'frames {tracks.n_frames}: load {t1 - t0:.3f} s, analyse {t2 - t1:.3f} s, '
          f'total {t2 - t0:.3f} s (goal < 2 s)')
    print(analysis.summary())


if __name__ == '__main__':
    main()
