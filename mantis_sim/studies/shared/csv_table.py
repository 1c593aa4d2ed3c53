"""Rows of a study's results (dicts) as a CSV file with a header."""
from __future__ import annotations

from collections.abc import Iterable, Sequence
import csv
from pathlib import Path


def write_rows(path: Path, rows: Iterable[dict], columns: Sequence[str] | None = None) -> Path:
    """``rows`` under a header: ``columns`` (a row's other keys left out), by default the first
    row's keys (a later row with another key is refused, as csv.DictWriter does)."""
    rows = list(rows)
    with open(path, 'w', newline='', encoding='utf-8') as handle:
        writer = csv.DictWriter(handle, list(columns) if columns is not None else list(rows[0]),
                                extrasaction='ignore' if columns is not None else 'raise')
        writer.writeheader()
        writer.writerows(rows)
    return path
