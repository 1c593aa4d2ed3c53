"""The marker finder and namer on the twenty real camera frames (test/data/real_frames,
PROVENANCE.md): each picture as a one-frame input finds and names every marker of the lab's
first frame, its centres matching the lab's up to a similarity (scale, rotation, shift, mirror)
within 5 % of the markers' spread, on at least 18 of the 20; no marker is ever named wrong (a
wrong name costs 20 % or more: no picture may land above 10 %)."""
from pathlib import Path
import sys

from conftest import data_file
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'bench'))
from bench_real_frames import judge, lab_markers  # noqa: E402

pytestmark = pytest.mark.slow

FOLDER = data_file('real_frames/first_frame_markers.csv').parent


def test_real_frames_found_and_named():
    lab = lab_markers(FOLDER / 'first_frame_markers.csv')
    assert len(lab) == 20
    rows = [judge(data_file(f'real_frames/{trial}.png'), markers)
            for trial, markers in sorted(lab.items())]
    passed = [r['trial'] for r in rows if r['ok']]
    assert len(passed) >= 18, [(r['trial'], r['missing'], r['residual']) for r in rows]
    for r in rows:
        assert r['residual'] <= 0.10, f'{r["trial"]}: a marker named wrong ({r})'
