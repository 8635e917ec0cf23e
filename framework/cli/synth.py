"""Render the built-in synthetic infant capture: videos, calibration.toml, clean plates and ground truth.

Writes OUT_DIR/videos/<camera>.mp4 (lossless H.264), OUT_DIR/calibration.toml (anipose, distorted
cameras), OUT_DIR/plates/<camera>.png (the empty mat) and OUT_DIR/ground_truth.zarr (per-frame infant masks and depth in the videos' pixels, labelled
surface points and joint centres over time). The folder appears only once complete. The adult's leg is
on by default: the reference study's captures show adults beside the mat, and the subject mask never
includes it, so it tests which component the segmenters keep (central by default) at no cost to the ground truth.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out_dir", type=Path, metavar="OUT_DIR", help="the capture folder to write (must not exist or be empty)")
    parser.add_argument("--num-frames", type=int, default=30, metavar="N", help="number of frames (default: 30)")
    parser.add_argument("--num-cameras", type=int, default=8, metavar="N", help="number of cameras on the ring (default: 8)")
    parser.add_argument("--width", type=int, default=256, help="image width in pixels (default: 256)")
    parser.add_argument("--height", type=int, default=192, help="image height in pixels (default: 192)")
    parser.add_argument("--seed", type=int, default=0, help="fixes the motion and the rig's small variations (default: 0)")
    parser.add_argument("--fps", type=float, default=30.0, help="frame rate (default: 30)")
    parser.add_argument("--adult-leg", action=argparse.BooleanOptionalAction, default=True,
                        help="an adult's leg standing beside the mat, at the edge of some views (default: on)")  # fmt: skip
    parser.add_argument("--slide", type=float, default=0.0, metavar="M_PER_S",
                        help="move the whole infant along +x at this speed in m/s (default: 0); at about 1 m/s it leaves "
                             "some views within a second — a failure regime for `mmcsplat stability`")  # fmt: skip
    parser.add_argument("--motion", default="natural", metavar="KIND",
                        help="natural (default): every joint swings; still-trunk: the torso, pelvis and head hold one pose, only "
                             "the limbs move; fast-kicks: quick kicks, the feet moving about their own width between frames at 30 fps")  # fmt: skip
    parser.add_argument("--monocular", action="store_true",
                        help="one camera orbiting the mat instead of the ring, written in the D-NeRF layout (transforms_train.json; "
                             "transforms_test.json: --num-cameras fixed held-out cameras every 5th frame); no adult's leg")  # fmt: skip
    parser.add_argument("--turns", type=float, default=1.0, help="with --monocular, orbits over the sequence (default: 1)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing OUT_DIR")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.synthetic import SynthConfig, synthesize

    config = SynthConfig(
        frames=args.num_frames, cameras=args.num_cameras, width=args.width, height=args.height,
        seed=args.seed, fps=args.fps, adult_leg=args.adult_leg, slide=args.slide, motion=args.motion,
    )  # fmt: skip
    if args.monocular:
        from mmcsplat.plugin_api.errors import InputError
        from mmcsplat.synthetic.monocular import synthesize_monocular

        if args.overwrite:
            raise InputError("--overwrite: a monocular capture is written to a new folder only")
        written = synthesize_monocular(args.out_dir, config, turns=args.turns, progress=not args.no_progress)
        print(f"wrote {written.out_dir}: {written.train_images} images of one orbiting camera and {written.heldout_images} held-out "
              f"images of {config.cameras} fixed cameras, {config.width}×{config.height}, in {written.seconds:.1f} s")
        return 0
    result = synthesize(args.out_dir, config, overwrite=args.overwrite, progress=not args.no_progress)
    print(f"wrote {result.out_dir}: {len(result.cameras)} cameras × {result.num_frames} frames of "
          f"{config.width}×{config.height} in {result.seconds:.1f} s")  # fmt: skip
    return 0
