"""Ingest a capture (a folder of videos, image sequences, d3dgs or D-NeRF data) into a session store.

Frames are undistorted (stored cameras have zero distortion) and optionally rescaled; the session is
written atomically, so a failed or interrupted ingest leaves no session behind.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from mmcsplat.configuration.registry import default_registry


def _names(text: str) -> list[str]:
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise argparse.ArgumentTypeError("expected comma-separated camera names")
    return names


def _frames(text: str) -> slice:
    from mmcsplat.pipeline.ingest import parse_frames

    try:
        return parse_frames(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", type=Path, help="the capture: a folder in one of the reader formats")
    parser.add_argument("out", help="the session to write (a path or URL ending in .zarr)")
    parser.add_argument("--format", choices=default_registry().names("reader"), help="the capture format (auto-detected when omitted)")
    parser.add_argument("--calibration", type=Path, help="calibration.toml to use instead of the one in SOURCE")
    parser.add_argument("--units", choices=("m", "mm"), default="m", help="length unit of the calibration's translations (default: m)")
    parser.add_argument("--frames", type=_frames, metavar="START:STOP[:STEP]", help="the frame indices to ingest (default: all)")
    parser.add_argument("--scale", type=float, default=1.0, help="resize factor for the stored images; K is scaled to match (default: 1)")
    parser.add_argument("--cameras", type=_names, metavar="A,B,…", help="ingest only these cameras")
    parser.add_argument("--holdout", type=_names, default=[], metavar="A,B,…", help="cameras kept for evaluation, not training")
    parser.add_argument("--plates", type=Path, metavar="DIR",
                        help="clean plates of the empty scene, one image per camera named after it (default: SOURCE/plates when it exists)")
    parser.add_argument("--set", dest="options", action="append", default=[], metavar="KEY=VALUE",
                        help="a reader parameter (see `mmcsplat plugins --show FORMAT`), read as TOML when it can be: fps=25, missing_frames=absent")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing session at OUT (never anything but a session)")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.configuration.config import apply_override
    from mmcsplat.pipeline.ingest import ingest

    options: dict = {}
    for option in args.options:
        options = apply_override(options, option, "--set")
    with warnings.catch_warnings():
        # Reader warnings (size mismatches, truncation) are user-facing: one line each, no source location.
        warnings.showwarning = lambda message, *_, **__: print(f"mmcsplat ingest: warning: {message}", file=sys.stderr)
        session = ingest(
            args.source,
            args.out,
            format=args.format,
            calibration=args.calibration,
            units=args.units,
            frames=args.frames,
            scale=args.scale,
            cameras=args.cameras,
            holdout=args.holdout,
            overwrite=args.overwrite,
            plates=args.plates,
            reader_options=options,
        )
    sizes = sorted({f"{camera.width}×{camera.height}" for camera in session.cameras})
    held = f" (held out: {', '.join(session.heldout)})" if session.heldout else ""
    plates = ", with clean plates" if session.provenance.get("plates") else ""
    print(f"wrote {args.out}: {len(session.cameras)} cameras{held}, {session.num_frames} frames at {session.fps:g} fps, {', '.join(sizes)}{plates}")
    return 0
