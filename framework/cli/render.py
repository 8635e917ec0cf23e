"""Render videos of a run: a novel-view loop around the rig, the tracking figure, expected depth.

--novel: a camera path through the training cameras in ring order (slerp of rotations, lerp of centres
and intrinsics); path frame j shows the Gaussians of frame j mod T, so the motion loops while the camera
goes round. --trajectories: 2 % of the foreground Gaussians with trails over their last 10 frames over
the rendered image of --camera (default: the held-out camera), as mp4 and a PNG strip of 5 frames.
--depth: expected depth in --camera, colour-mapped over one range for the whole sequence. --landmarks: the
landmarks of `mmcsplat landmarks` with their trails on --camera's real images, cropped to the subject. A run without
tracks renders its first-frame fit. Videos are H.264 (yuv420p) mp4, playable in browsers. An unfinished run (its fit
or tracking stopped) is refused unless --allow-incomplete, and one another command is writing always; renders into the
run's own folder hold its lock, so that no tracking replaces what they show while they are made.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from pathlib import Path

from mmcsplat.storage.run import RENDERS_DIR


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory of `mmcsplat fit` (with RUN/tracks.zarr after `mmcsplat track`)")
    parser.add_argument("--novel", action="store_true", help="novel-view camera path → OUT/novel.mp4")
    parser.add_argument("--trajectories", action="store_true", help="tracking figure → OUT/trajectories_CAMERA.mp4 and .png")
    parser.add_argument("--depth", action="store_true", help="expected depth → OUT/depth_CAMERA.mp4")
    parser.add_argument("--landmarks", action="store_true", help="RUN/landmarks.csv on the camera's images → OUT/landmarks_CAMERA.mp4")
    parser.add_argument("--camera", help="camera of --trajectories, --depth and --landmarks (default: the run's held-out camera)")
    parser.add_argument("--frames-per-segment", type=int, metavar="N",
                        help="--novel path frames from one ring camera to the next (default: enough to show every frame, ≥ 15)")
    parser.add_argument("--scale", type=float, default=1.0, help="output image scale, e.g. 0.5 for half size (default 1)")
    parser.add_argument("--backend", help="renderer backend by name (default: the one that fitted)")
    parser.add_argument("--out", type=Path, help="output directory (default: RUN/renders)")
    parser.add_argument("--allow-incomplete", action="store_true", help="render a run whose fit or tracking is not finished (refused without "
                                                                        "it; the videos carry no label, the command warns)")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.cli.main import CommandError
    from mmcsplat.pipeline.run_frames import RunStates
    from mmcsplat.storage.atomic import remove_local_tree
    from mmcsplat.storage.completeness import require_finished
    from mmcsplat.storage.locking import run_lock

    if not (args.novel or args.trajectories or args.depth or args.landmarks):
        raise CommandError("choose at least one output: --novel, --trajectories, --depth or --landmarks")
    if args.frames_per_segment is not None and args.frames_per_segment < 1:
        raise CommandError(f"--frames-per-segment must be ≥ 1, got {args.frames_per_segment}")
    states = RunStates(args.run)
    for problem in require_finished(args.run, states.info, args.allow_incomplete):
        print(f"mmcsplat render: warning: {args.run} is unfinished, its renders show it so: {problem}", file=sys.stderr)
    if args.trajectories or args.depth or args.landmarks:
        states.camera(args.camera)  # an unknown camera fails before anything is rendered
    out = args.out or args.run / RENDERS_DIR
    if out.exists() and not out.is_dir():
        raise CommandError(f"--out {out} is a file, not a folder to write the renders into: name a folder")
    inside = Path(os.path.abspath(out)).is_relative_to(os.path.abspath(args.run))
    with run_lock(args.run) if inside else contextlib.nullcontext():
        if inside:  # what a killed render left in the run's folder (only a holder of its lock may take it away)
            for leftover in out.glob(".*.tmp"):
                remove_local_tree(leftover)
        return _render(args, states, out)


def _render(args: argparse.Namespace, states, out: Path) -> int:
    from mmcsplat.outputs.renders import RunRenderer, render_depth, render_novel, render_trajectories

    out.mkdir(parents=True, exist_ok=True)
    renderer = RunRenderer(states, backend=args.backend, scale=args.scale, progress=not args.no_progress)
    if states.tracks is None:
        print(f"{args.run}: no tracks, rendering the first-frame fit")
    written = []
    if args.novel:
        written.append(render_novel(renderer, out, args.frames_per_segment))
    if args.trajectories:
        written.extend(render_trajectories(renderer, out, args.camera))
    if args.depth:
        path, (near, far) = render_depth(renderer, out, args.camera)
        print(f"depth range {near:.3f}–{far:.3f} m")
        written.append(path)
    if args.landmarks:
        from mmcsplat.outputs.landmark_video import render_landmarks

        written.append(render_landmarks(args.run, out, args.camera, progress=not args.no_progress))
    for path in written:
        print(path)
    return 0
