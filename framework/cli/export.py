"""Export a run's Gaussians per frame, in the PLY layout common 3DGS viewers read.

--ply DIR writes one PLY per frame (frame_NNNN.ply, by session frame): position, SH degree-0 colour,
logit opacity, log scales, quaternion.

A run with tracks exports every tracked frame; without tracks, its first-frame fit.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmcsplat.cli.options import add_progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory of `mmcsplat fit` (with RUN/tracks.zarr after `mmcsplat track`)")
    parser.add_argument("--ply", type=Path, required=True, metavar="DIR", help="directory to write the PLY files into")
    add_progress(parser)


def run(args: argparse.Namespace) -> int:
    from mmcsplat.outputs.ply import export_ply

    paths = export_ply(args.run, args.ply, progress=not args.no_progress)
    print(f"{args.ply}: {len(paths)} PLY file(s), {paths[0].name} … {paths[-1].name}")
    return 0
