"""Compute a session's optical flow between consecutive frames, for flow-guided tracking.

OpenCV's DIS flow, forward and backward, with a per-pixel confidence from their consistency, in every
training camera (or --cameras), stored in the session. An interrupted run resumes where it stopped; a
session with flow of another preset gets it replaced. `track` with the iterative dynamics predicts each
frame from it (docs/dynamics.md, "Flow-guided prediction").
"""

from __future__ import annotations

import argparse

from mmcsplat.cli.options import add_names, add_progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from mmcsplat.pipeline.flow import DEFAULT_PRESET, PRESETS

    parser.add_argument("session", help="the session to update (a path or URL)")
    add_names(parser, "--cameras", "compute only these cameras' flow (default: the training cameras)")
    parser.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET, help=f"DIS preset (default: {DEFAULT_PRESET})")
    add_progress(parser)


def run(args: argparse.Namespace) -> int:
    from mmcsplat.pipeline.flow import compute_flow

    for summary in compute_flow(args.session, args.cameras, args.preset, progress=not args.no_progress):
        confidence = "" if summary.median_confidence is None else f", median confidence {summary.median_confidence:.2f}"
        kept = f", {summary.resumed} kept from an interrupted run" if summary.resumed and summary.computed else ""
        print(f"{summary.camera}: {summary.computed or summary.resumed} pairs of frames{kept}{confidence}")
    return 0
