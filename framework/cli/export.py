"""Export a run's Gaussians for 3DGS viewers and tools: per-frame PLY files, or the reference trainer's model folder.

--ply DIR writes one PLY per run frame (frame_NNNN.ply, by session frame; DIR replaced whole, and refused when it holds
anything but an earlier export's frames): position, SH degree-0 colour,
logit opacity, log scales, quaternion. --full-sh writes them in the reference 3DGS layout instead: the
same properties plus f_rest_0..44, zero (SH degree 3; the fit's colour is view-independent).

--inria DIR writes one run frame (--frame K, default 0: the first) as the reference trainer's model
folder, which its SIBR viewer opens: DIR/cfg_args, DIR/cameras.json (every session camera) and
DIR/point_cloud/iteration_N/point_cloud.ply (full layout; N the fit's iteration count). DIR must not exist
or be empty; the folder is written under a temporary name and renamed into place.

--transforms DIR writes the rig and the fitted frame's images (and masks) as a nerfstudio dataset folder:
DIR/transforms.json (OPENCV intrinsics per camera, camera-to-world in OpenGL axes, train/val split as the
run's) and DIR/images/CAMERA.png; the cameras.json of --inria is the reference trainer's view of the rig.

--trc FILE, --csv FILE, --c3d FILE write the run's carried landmarks (RUN/landmarks.csv of `mmcsplat
landmarks`): TRC as Pose2Sim writes it (Y-up axes, metres; OpenSim reads it), CSV one row per frame and
landmark, C3D in millimetres through ezc3d.

A run with tracks exports every tracked frame; without tracks, its first-frame fit (run frame 0).
An unfinished run (its fit or tracking not complete) is refused; with --allow-incomplete it is exported,
with a warning and every file labelled: a comment in every PLY header, an `Incomplete` header key in the
TRC, an `incomplete` column in the CSV and the parameter MMCSPLAT:INCOMPLETE in the C3D, each saying what
is unfinished (landmarks carried before the run was finished stay labelled). --ply files are written
beside DIR and moved in once all are whole.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mmcsplat.cli.options import add_allow_incomplete


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory of `mmcsplat fit` (with RUN/tracks.zarr after `mmcsplat track`)")
    parser.add_argument("--ply", type=Path, metavar="DIR", help="directory to write one PLY per run frame into")
    parser.add_argument("--full-sh", action="store_true",
                        help="--ply files in the reference 3DGS layout (f_rest_0..44 zero-padded to SH degree 3) instead of SH degree 0")
    parser.add_argument("--inria", type=Path, metavar="DIR",
                        help="write the reference 3DGS trainer's model folder here (cfg_args, cameras.json, point_cloud/iteration_N/point_cloud.ply)")
    parser.add_argument("--transforms", type=Path, metavar="DIR",
                        help="write the rig and the fitted frame's images as a nerfstudio dataset folder (transforms.json, images/, masks/)")
    parser.add_argument("--trc", type=Path, metavar="FILE", help="the run's landmarks as a TRC file (OpenSim, Pose2Sim)")
    parser.add_argument("--csv", type=Path, metavar="FILE", help="the run's landmarks as CSV: frame (the capture's number), time, name, x, y, z, spread_mm, confidence")
    parser.add_argument("--c3d", type=Path, metavar="FILE", help="the run's landmarks as a C3D file (millimetres)")
    parser.add_argument("--frame", type=int, metavar="K",
                        help="the run frame --inria writes (0 to frames − 1; default 0, the first)")
    add_allow_incomplete(parser)


def run(args: argparse.Namespace) -> int:
    from mmcsplat.cli.main import CommandError
    from mmcsplat.outputs.ply import FULL_SH_DEGREE, export_ply
    from mmcsplat.storage.completeness import require_finished
    from mmcsplat.storage.run_info import RunInfo

    landmark_files = {"trc": args.trc, "csv": args.csv, "c3d": args.c3d}
    if args.ply is None and args.inria is None and args.transforms is None and not any(landmark_files.values()):
        raise CommandError("choose at least one output: --ply DIR, --inria DIR, --transforms DIR, --trc FILE, --csv FILE or --c3d FILE")
    if args.full_sh and args.ply is None:
        raise CommandError("--full-sh sets the layout of --ply files (--inria always writes the full layout)")
    if args.frame is not None and args.inria is None:
        raise CommandError("--frame picks the run frame of --inria (--ply writes every frame)")
    unfinished = require_finished(args.run, RunInfo.read(args.run), args.allow_incomplete)
    comments = [f"mmcsplat: incomplete run {args.run}: {problem}" for problem in unfinished]
    for problem in unfinished:
        print(f"mmcsplat export: warning: {args.run} is unfinished, its outputs are incomplete: {problem}", file=sys.stderr)
    if args.inria is not None:
        from mmcsplat.outputs.inria_model import export_inria

        frame = args.frame or 0
        ply = export_inria(args.run, args.inria, frame=frame, comments=comments)
        print(f"{args.inria}: reference 3DGS model folder of run frame {frame}, {ply.relative_to(args.inria)}")
    if args.transforms is not None:
        from mmcsplat.outputs.transforms_json import export_transforms

        path = export_transforms(args.run, args.transforms)
        print(f"{path}: nerfstudio dataset of the fitted frame")
    if any(landmark_files.values()):
        from mmcsplat.outputs.landmark_export import export_landmarks

        for path in export_landmarks(args.run, **landmark_files, unfinished=unfinished):
            print(f"{path}: the run's landmarks")
    if args.ply is not None:
        paths = export_ply(args.run, args.ply, progress=not args.no_progress, sh_degree=FULL_SH_DEGREE if args.full_sh else 0,
                           comments=comments)
        print(f"{args.ply}: {len(paths)} PLY file(s), {paths[0].name} … {paths[-1].name}")
    return 0
