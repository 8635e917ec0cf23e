"""Write one self-contained HTML page of a run or a study: images and videos embedded, nothing to fetch.

A run directory (`mmcsplat fit`): the held-out camera's colour, depth and segmentation rendered beside
the ground truth, the metrics of `mmcsplat evaluate` (tracking and a per-frame chart when tracked), and
the figures and videos `mmcsplat render` wrote into RUN/renders/ (the page names the command for those
missing). A study output (`mmcsplat compare`): its results table, findings and charts.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmcsplat.cli.options import add_allow_incomplete


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", type=Path, metavar="RUN_OR_STUDY", help="a run directory or the output directory of a study")
    parser.add_argument("--out", type=Path, metavar="FILE", help="HTML file to write (default: RUN_OR_STUDY/report.html)")
    parser.add_argument("--backend", help="renderer backend for a run's views (default: the one that fitted)")
    add_allow_incomplete(parser)


def run(args: argparse.Namespace) -> int:
    from mmcsplat.outputs.report import write_report

    target = write_report(args.path, args.out, backend=args.backend, allow_incomplete=args.allow_incomplete)
    print(f"{target} ({target.stat().st_size / 1e6:.1f} MB)")
    return 0
