"""Segment the subject in a session's frames with a segmenter plugin and store the masks (and labels).

The session is updated atomically: the new masks and labels replace the old ones all at once when every
selected camera is done, and a failure or interruption leaves the session exactly as it was.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from mmcsplat.pipeline.segment import segment_session


def _cameras(values: list[str]) -> list[str]:
    return [name.strip() for value in values for name in value.split(",") if name.strip()]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="the session to update (a path or URL)")
    parser.add_argument("--segmenter", required=True, metavar="NAME", help="a registered segmenter (see `mmcsplat plugins`)")
    parser.add_argument(
        "--set", dest="params", action="append", default=[], metavar="KEY=VALUE",
        help="a segmenter parameter; the value is read as TOML when it can be, dotted keys make tables (remap.toy=person)",
    )
    parser.add_argument("--cameras", nargs="+", metavar="CAMERA", help="segment only these cameras (default: all)")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.configuration.config import apply_override

    params: dict[str, Any] = {}
    for override in args.params:
        params = apply_override(params, override, "--set")
    summaries = segment_session(args.session, args.segmenter, params, _cameras(args.cameras) if args.cameras else None)
    for summary in summaries:
        print(f"{summary.camera}: {summary.frames} frames, mean coverage {summary.coverage:.1%}, {summary.empty} empty")
        if summary.frames and summary.empty == summary.frames:
            print(f"mmcsplat segment: warning: every mask of camera {summary.camera!r} is empty", file=sys.stderr)
    print(f"wrote masks into {args.session} with segmenter {args.segmenter!r}")
    return 0
