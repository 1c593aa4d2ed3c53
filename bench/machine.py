"""What every figure in docs/ is stamped with: the commit it was measured at and the machine's
yardstick (this shared VM's speed drifts by up to two-fold from hour to hour)."""
from __future__ import annotations

import datetime
import os
from pathlib import Path
import subprocess
import time

REPO = Path(__file__).resolve().parent.parent


def yardstick_s() -> float:
    """Seconds for a pure-Python loop, sum(range(3e7)): best of three."""
    best = float('inf')
    for _ in range(3):
        start = time.perf_counter()
        sum(range(3 * 10 ** 7))
        best = min(best, time.perf_counter() - start)
    return best


def commit() -> str:
    """The checked-out commit, with '+changes' when the tree differs from it."""
    def git(*args):
        return subprocess.run(['git', *args], cwd=REPO, capture_output=True, text=True,
                              check=False).stdout.strip()
    head = git('rev-parse', '--short', 'HEAD') or 'unknown'
    return head + ('+changes' if git('status', '--porcelain', '--untracked-files=no') else '')


def stamp() -> str:
    """One line for a table's caption: date, commit, cores, yardstick."""
    today = datetime.datetime.now(datetime.UTC).strftime('%Y-%m-%d %H:%M UTC')
    return (f'measured {today} at commit {commit()} on {os.cpu_count()} cores; yardstick '
            f'(sum(range(3e7)), best of 3) {yardstick_s():.2f} s')


def replace_section(path: Path, heading: str, text: str) -> None:
    """Put ``text`` under ``heading`` (a Markdown '## ' line) in ``path``: in place of what was
    there up to the next '## ' heading, or at the end."""
    doc = path.read_text(encoding='utf-8')
    head, found, tail = doc.partition(heading)
    rest = tail[tail.find('\n## '):] if found and '\n## ' in tail else ''
    path.write_text(head.rstrip('\n') + '\n\n' + heading + '\n\n' + text.rstrip('\n') + '\n'
                    + rest, encoding='utf-8')
