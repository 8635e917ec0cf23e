"""Ingest a capture (videos, image sequences, d3dgs, D-NeRF, nerfstudio or COLMAP data) into a session store.

Frames are undistorted (stored cameras have zero distortion) and optionally rescaled; the session is
written atomically, so a failed or interrupted ingest leaves no session behind.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmcsplat.cli.options import add_frames, add_names, add_settings, add_units, scale_value, settings_table
from mmcsplat.configuration.registry import default_registry
from mmcsplat.pipeline.image_scale import AUTO_LONGEST_SIDE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", type=Path, help="the capture: a folder in one of the reader formats")
    parser.add_argument("out", help="the session to write (a path or URL ending in .zarr)")
    parser.add_argument("--format", choices=default_registry().names("reader"), help="the capture format (auto-detected when omitted)")
    parser.add_argument("--calibration", type=Path, help="calibration to use instead of the one in SOURCE: a .toml (anipose, Pose2Sim, Caliscope's camera_array.toml), "
                        "Qualisys's .qca.txt, EasyMocap's intri.yml or extri.yml (the other beside it) or their folder, or "
                        "an OpenCap camera's cameraIntrinsicsExtrinsics.pickle (the rig: every camera folder beside it)")
    add_units(parser)
    add_frames(parser, "the capture's frames to ingest, by its own numbers (default: all); the session numbers them from 0")
    parser.add_argument("--scale", type=scale_value, default=1.0, help="resize factor in (0, 1] for the stored images, or auto: their longer side "
                        f"at most {AUTO_LONGEST_SIDE} px, never enlarged; K is scaled to match (default: 1)")
    add_names(parser, "--cameras", "ingest only these cameras, in this order")
    add_names(parser, "--holdout", "cameras kept for evaluation, not training", default=[])
    parser.add_argument("--plates", type=Path, metavar="DIR",
                        help="clean plates of the empty scene, one image per camera named after it (default: SOURCE/plates when it exists)")
    add_settings(parser, "a reader parameter (`mmcsplat plugins --show FORMAT`), read as TOML when it can be: fps=25, missing_frames=absent",
                 dest="options")
    parser.add_argument("--skip-missing", action="store_true",
                        help="ingest without the images the capture lists but lacks, or the moments a Caliscope camera missed, saying how many "
                             "(the reader option missing_frames=absent)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing session at OUT (never anything but a session)")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.pipeline.ingest import ingest, units_chosen

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
        reader_options=settings_table(args.options),
        skip_missing=args.skip_missing,
        progress=not args.no_progress,
    )
    sizes = sorted({f"{camera.width}×{camera.height}" for camera in session.cameras})
    held = f" (held out: {', '.join(session.heldout)})" if session.heldout else ""
    plates = ", with clean plates" if session.provenance.get("plates") else ""
    chosen = units_chosen(session, args.units)
    units = f", calibration read in {chosen}" if chosen else ""
    print(f"wrote {args.out}: {len(session.cameras)} cameras{held}, {session.num_frames} frames at {session.fps:g} fps, {', '.join(sizes)}{plates}{units}")
    return 0
