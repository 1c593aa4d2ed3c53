"""What accuracy costs in time on one scene (work-precision), as accuracy_SCENE.md in docs/.

    .venv/bin/python bench/accuracy_report.py --scene air_23mm [--repeats 3]

Every solver over the tolerance ladder of `mantis bench accuracy`, against the scene solved by
DOP853 and Radau at their tightest tolerances; the table with the commit and yardstick.
"""
from __future__ import annotations

import argparse
import sys

from machine import REPO, stamp

from mantis_sim.studies.design import benchmark


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--scene', required=True)
    parser.add_argument('--repeats', type=int, default=3)
    args = parser.parse_args()
    table = benchmark.accuracy_table(args.scene, repeats=args.repeats)
    text = (f'# Accuracy against time: {args.scene}\n\nWritten by `bench/accuracy_report.py` '
            f'({stamp()}; wall times are the median of {args.repeats} runs).\n\n'
            + benchmark.format_table(table, markdown=True) + '\n')
    path = REPO / 'docs' / f'accuracy_{args.scene}.md'
    path.write_text(text, encoding='utf-8')
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
