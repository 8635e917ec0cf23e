"""Compute a session's optical flow between consecutive frames, for flow-guided tracking.

OpenCV's DIS flow, forward and backward, with a per-pixel confidence from their consistency, in every
training camera (or --cameras), stored in the session. An interrupted run resumes where it stopped; flow
already computed with the same preset is kept, flow of another preset replaced. `track` with the iterative
dynamics predicts each frame from it (docs/dynamics.md, "Flow-guided prediction"). With --joints (a TRC
file, or a synthetic capture's ground truth), says how well the flow lifted to 3D predicts each frame's joints
from the previous frame's.
"""

from __future__ import annotations

import argparse

from mmcsplat.cli.options import add_names


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from mmcsplat.pipeline.flow import DEFAULT_PRESET, PRESETS

    parser.add_argument("session", help="the session to update (a path or URL)")
    add_names(parser, "--cameras", "compute only these cameras' flow (default: the training cameras)")
    parser.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET, help=f"DIS preset: OpenCV's ultrafast, fast or medium, or fine, "
                        f"medium at full resolution on images upsampled ×2, which follows fast thin limbs (default: {DEFAULT_PRESET})")
    parser.add_argument("--joints", metavar="TRC|GROUND_TRUTH", help="joints: triangulated (a TRC file, Pose2Sim's axes) or a synthetic capture's "
                        "(its folder or ground_truth.zarr): print how well the lifted flow predicts their next positions, beside constant velocity")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.pipeline.flow import compute_flow

    for summary in compute_flow(args.session, args.cameras, args.preset, progress=not args.no_progress):
        if not summary.computed:
            print(f"{summary.camera}: {summary.kept} pairs of frames already computed with this preset")
            continue
        kept = f" ({summary.kept} kept from an interrupted run)" if summary.kept else ""
        print(f"{summary.camera}: {summary.computed} pairs of frames{kept}, {summary.cpu_s_per_pair:.3f} CPU s per pair, "
              f"{summary.confident_share:.1%} of pixels with confidence above 0.5")
    if args.joints:
        from mmcsplat.analysis.flow_joints import joint_prediction_errors

        figures = joint_prediction_errors(args.session, args.joints).summary()
        print(f"joints' next positions, {figures['lifted_share']:.0%} lifted (median / p90 mm, all joints; moving ones, {figures['moving_share']:.0%}):")
        for name, label in (("flow", "lifted flow"), ("constant_velocity", "constant velocity"), ("still", "standing still")):
            print(f"  {label}: {figures[f'{name}_median_mm']:.1f} / {figures[f'{name}_p90_mm']:.1f}; "
                  f"moving {figures[f'moving_{name}_median_mm']:.1f} / {figures[f'moving_{name}_p90_mm']:.1f}")
    return 0
