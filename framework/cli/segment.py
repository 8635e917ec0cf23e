"""Segment the subject in a session's frames with a segmenter plugin and store the masks (and labels).

The session is updated atomically: the new masks and labels replace the old ones all at once when every
selected camera is done, and a failure or interruption leaves the session exactly as it was.
"""

from __future__ import annotations

import argparse
import sys

from mmcsplat.cli.options import add_names, add_settings, settings_table
from mmcsplat.pipeline.segment import segment_session

#: Mean mask coverage outside which a camera's masks are suspect (nothing found, or the whole image).
MIN_COVERAGE, MAX_COVERAGE = 0.001, 0.9


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="the session to update (a path or URL)")
    parser.add_argument("--segmenter", required=True, metavar="NAME", help="a registered segmenter (see `mmcsplat plugins`)")
    add_settings(parser, "a segmenter parameter (`mmcsplat plugins --show NAME`); read as TOML when it can be, dotted keys make "
                         "tables (remap.toy=person)", dest="params")
    add_names(parser, "--cameras", "segment only these cameras (default: all)")
    parser.add_argument("--consistent", action="store_true",
                        help="then keep only the mask pixels most other cameras' masks agree on (drops what one view alone sees)")


def run(args: argparse.Namespace) -> int:
    summaries = segment_session(args.session, args.segmenter, settings_table(args.params), args.cameras,
                                progress=not args.no_progress, consistent=args.consistent)
    for summary in summaries:
        print(f"{summary.camera}: {summary.frames} frames, mean coverage {summary.coverage:.1%}, {summary.empty} empty")
        if summary.frames and summary.empty == summary.frames:
            print(f"mmcsplat segment: warning: every mask of camera {summary.camera!r} is empty", file=sys.stderr)
        elif summary.frames and not MIN_COVERAGE <= summary.coverage <= MAX_COVERAGE:
            print(f"mmcsplat segment: warning: camera {summary.camera!r}'s masks cover {summary.coverage:.2%} of its images on average: "
                  f"{'almost nothing' if summary.coverage < MIN_COVERAGE else 'almost everything'} — check the segmenter's settings", file=sys.stderr)
    print(f"wrote masks into {args.session} with segmenter {args.segmenter!r}")
    return 0
