"""Carry named landmarks (joints, keypoints) through a run: RUN/landmarks.csv and RUN/landmarks.json.

The landmarks of --source are bound to the subject's Gaussians at the run's fitted frame (the 8 nearest
within 10 cm, anchored in each one's local frame), from the source's first 7 frames (--bind-frames: each
carried back to the fitted frame, their median taken, so that one frame's error in the source is outvoted),
and carried through every tracked frame (a run without tracks gives the fitted frame alone). Sources
(`mmcsplat plugins landmarks`): trc and csv files of 3D points, openpose keypoints triangulated in the
session's cameras, the synthetic capture's joints. Where the source knows the landmarks at the frames after
those it was bound from, the carried ones are scored against them (3D, mm); --keypoints scores them against
2D detections in every camera (px). Their movement measures (speeds, paths, ranges, rhythms, left/right
symmetry, knee, elbow, hip and shoulder flexion) go to RUN/movement.json and RUN/movement.csv. Every frame, each landmark is judged against the training cameras' subject masks and,
where the session has optical flow (`mmcsplat flow`), against the images' motion: the landmarks the tracks
lost (off the masks, or slipped from the flow, in most cameras for 3 frames or more) and from which frame are
printed and recorded in RUN/landmarks.json. `mmcsplat export RUN --trc/--csv/--c3d` writes the landmarks for OpenSim, Pose2Sim and
motion-lab tools; `mmcsplat report RUN` plots them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmcsplat.cli.options import add_allow_incomplete, add_settings, settings_table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory of `mmcsplat fit` (with RUN/tracks.zarr after `mmcsplat track`)")
    parser.add_argument("--source", required=True, metavar="NAME", help="the landmark source: trc, csv, openpose, synthetic or a plugin's name")
    add_settings(parser, "a parameter of the source (`mmcsplat plugins --show landmarks:NAME`), e.g. path=joints.trc")
    parser.add_argument("--keypoints", metavar="NAME", help="a keypoint source (openpose) whose 2D detections score the carried landmarks per camera")
    add_settings(parser, "a parameter of the --keypoints source, e.g. folder=pose_2d", dest="keypoint_overrides", flag="--keypoints-set")
    parser.add_argument("--anchors", type=int, default=8, metavar="K", help="Gaussians carrying each landmark (default 8)")
    parser.add_argument("--max-distance", type=float, default=0.1, metavar="M",
                        help="metres within which a Gaussian may carry a landmark (default 0.1); farther landmarks are left out, not invented")
    parser.add_argument("--bind-frames", type=int, metavar="N",
                        help="the source's first N frames bind the landmarks, and are not scored (default 7; 1, the fitted frame "
                             "alone, for a source of exact landmarks: synthetic)")
    add_allow_incomplete(parser)


def run(args: argparse.Namespace) -> int:
    from mmcsplat.analysis.lost_landmarks import lost_line
    from mmcsplat.cli.main import CommandError
    from mmcsplat.pipeline.landmarks import track_landmarks
    from mmcsplat.storage.run import LANDMARKS_CSV, LANDMARKS_INFO, MOVEMENT_CSV, MOVEMENT_JSON

    if args.anchors < 1 or not args.max_distance > 0 or (args.bind_frames is not None and args.bind_frames < 1):
        raise CommandError(f"--anchors and --bind-frames must be ≥ 1 and --max-distance > 0, got {args.anchors}, {args.bind_frames} and "
                           f"{args.max_distance}")
    if args.keypoint_overrides and not args.keypoints:
        raise CommandError("--keypoints-set … needs --keypoints NAME")
    result = track_landmarks(args.run, args.source, settings_table(args.overrides), keypoints=args.keypoints,
                             keypoint_params=settings_table(args.keypoint_overrides), anchors=args.anchors, max_distance=args.max_distance,
                             bind_frames=args.bind_frames, allow_incomplete=args.allow_incomplete)
    info = result.info
    bound = len(info["names"]) - len(info["unbound"])
    print(f"{args.run / LANDMARKS_CSV}: {bound} landmarks over {info['frames'][1] - info['frames'][0]} frames"
          + (f"; left out (no subject Gaussian within {args.max_distance * 100:.0f} cm): {', '.join(info['unbound'])}" if info["unbound"] else ""))
    print(f"{args.run / MOVEMENT_JSON} and {MOVEMENT_CSV}: the movement measures, {len(result.movement['joint_angles'])} joint angles"
          + (f" ({len(result.movement['joint_angles_left_out'])} left out: their landmarks are absent)" if result.movement["joint_angles_left_out"] else ""))
    print(f"{args.run / LANDMARKS_INFO}: {lost_line(info['lost'])}")
    accuracy = info.get("accuracy_3d")
    if accuracy and accuracy["median_mm"] is not None:
        moving = (f"; where they moved > 1 cm: {accuracy['moving_median_mm']:.1f} mm against {accuracy['still_moving_median_mm']:.1f} mm held still"
                  if accuracy["moving_median_mm"] is not None else "")
        print(f"3D error against {args.source}: median {accuracy['median_mm']:.1f} mm, 90th percentile {accuracy['p90_mm']:.1f} mm{moving}")
    floor = info.get("reference_floor")
    if floor:
        print(f"the source's own floor: a body with its bones at the bind frames' lengths, placed nearest it in every frame, is "
              f"{floor['median_mm']:.1f} mm from it (90th percentile {floor['p90_mm']:.1f}); the carried landmarks are {floor['carried_median_mm']:.1f} mm "
              f"from that body")
    for camera, scores in info.get("accuracy_2d", {}).items():
        if scores["carried_median_px"] is not None:
            body = f", that body {scores['floor_median_source_px']:.1f} px" if scores.get("floor_median_source_px") is not None else ""
            print(f"2D error in {camera}{' (held out)' if scores['heldout'] else ''}: carried {scores['carried_median_source_px']:.1f} px, "
                  f"the source's own landmarks {scores['reference_median_source_px']:.1f} px{body} (median over {scores['detections']} detections, "
                  f"pixels of the recorded video)")
    return 0
