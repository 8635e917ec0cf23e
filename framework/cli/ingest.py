"""Ingest a capture (videos, image sequences, d3dgs, D-NeRF, nerfstudio or COLMAP data) into a session store.

Frames are undistorted (stored cameras have zero distortion) and optionally rescaled; the session is
written atomically, so a failed or interrupted ingest leaves no session behind.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmcsplat.cli.options import add_frames, add_names, add_settings, scale_value, settings_table
from mmcsplat.configuration.registry import default_registry
from mmcsplat.pipeline.image_scale import AUTO_LONGEST_SIDE
from mmcsplat.storage.calibration import AUTO_UNITS, UNIT_CHOICES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", type=Path, help="the capture: a folder in one of the reader formats")
    parser.add_argument("out", help="the session to write (a path or URL ending in .zarr)")
    parser.add_argument("--format", choices=default_registry().names("reader"), help="the capture format (auto-detected when omitted)")
    parser.add_argument("--calibration", type=Path, help="calibration to use instead of the one in SOURCE: a .toml (anipose, Pose2Sim, Caliscope's camera_array.toml), "
                        "Qualisys's .qca.txt, or EasyMocap's intri.yml or extri.yml (the other beside it) or their folder")
    parser.add_argument("--units", choices=UNIT_CHOICES, default=AUTO_UNITS, help="length unit of the calibration's translations (default auto: metres, or millimetres where only they put the cameras 5 cm–50 m from their centre; a Qualisys .qca.txt is millimetres whatever this says)")
    add_frames(parser, "the frame indices to ingest (default: all)")
    parser.add_argument("--scale", type=scale_value, default=1.0, help="resize factor for the stored images, or auto: their longer side "
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
    from mmcsplat.pipeline.ingest import ingest

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
    read_in = session.provenance.get("reader", {}).get("units")
    units = f", calibration read in {read_in}" if args.units == AUTO_UNITS and read_in not in (None, "m") else ""
    print(f"wrote {args.out}: {len(session.cameras)} cameras{held}, {session.num_frames} frames at {session.fps:g} fps, {', '.join(sizes)}{plates}{units}")
    return 0
