"""Run your own capture end to end: ingest, masks, plates, fit, track, evaluate, landmarks, renders, report.

For a rig's own folder (a Pose2Sim project, an anipose session, videos beside a calibration): ingests it at
--scale, makes subject masks from its 2D keypoints (pose_2d/, pose/, pose-2d/, FreeMoCap's output_data/raw_data/, a Caliscope tracker's xy_*.csv,
an OpenCap session's phones' OutputPkl/, or --keypoints: OpenPose, SLEAP, DeepLabCut, FreeMoCap, Caliscope or OpenCap; else against its
recorded plates; else from the subject's motion; or with the segmenter --segmenter names), estimates clean plates with the
subject masked out and refines the masks against them (not --segmenter's), fits the first
frame with the start region sized from the masks' visual hull, tracks the sequence, evaluates on the
held-out cameras, carries the joints of a TRC file (the capture's single *.trc, else Pose2Sim's pose-3d/*.trc, or --joints; a synthetic
capture's true joints without one; else its 2D keypoints triangulated) and scores them against it and the keypoints, renders the tracking figure and the landmark overlay, and writes the
report. Steps already done in OUT are reused, so a rerun resumes; docs/real-data.md walks through it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmcsplat.cli.options import add_frames, add_names, add_settings, add_units, scale_value
from mmcsplat.pipeline.image_scale import AUTO_LONGEST_SIDE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from mmcsplat.jobs.capture import DEFAULT_CONFIG, DEFAULT_SCALE, TRACK_FLOW_GAIN, TRACK_LAMBDA_PARTS, TRACK_MEANS_LR
    from mmcsplat.training.frame_steps import AUTO_STEPS, FEWEST_STEPS, STEPS_PER_SECOND

    parser.add_argument("capture", type=Path, help="the capture folder (videos or images and a calibration)")
    parser.add_argument("--out", required=True, type=Path, help="output directory (created; reused steps are skipped)")
    parser.add_argument("--calibration", help="calibration .toml (anipose, Pose2Sim, Caliscope), Qualisys .qca.txt, EasyMocap intri.yml or an OpenCap "
                        "camera's .pickle (default: the capture's own, see docs/ingest.md)")
    add_units(parser)
    parser.add_argument("--scale", type=scale_value, default=DEFAULT_SCALE, help="resize factor in (0, 1] of the stored images, or auto (the "
                        f"default): their longer side at most {AUTO_LONGEST_SIDE} px, never enlarged (0.25 for 1080 × 1920 video)")
    add_frames(parser, "the capture's frames to use, by its own numbers (default: all, or from where a trimmed TRC starts)")
    add_names(parser, "--cameras", "use only these cameras (default: all): leaves out a broken one, which is then never read or checked")
    add_names(parser, "--holdout", "cameras kept for evaluation (default: the capture format's, else none)")
    parser.add_argument("--keypoints", help="2D keypoints: a folder of OpenPose JSON folders per camera, or of SLEAP (.slp, .analysis.h5) or "
                        "DeepLabCut (.csv, .h5) files per camera, or one such file, or FreeMoCap's .npy or Caliscope's xy_TRACKER.csv of every camera, or an OpenCap session's folder (default: CAPTURE/pose_2d, else Pose2Sim's pose-associated, pose-sync or pose, else anipose's pose-2d-filtered or pose-2d, else FreeMoCap's output_data/raw_data/*2dData*.npy, else a Caliscope body tracker's TRACKER/xy_TRACKER.csv, else an OpenCap session's Videos/*/OutputPkl/, when there is one)")
    add_settings(parser, "a parameter of the keypoints' source (`mmcsplat plugins --show landmarks:openpose`, sleap, deeplabcut), e.g. "
                 "camera_map={cam_01=\"left\"} where the keypoints' names differ from the calibration's; the reader's camera_map and "
                 "trial (--reader-set) name the keypoints' files too unless this gives theirs", dest="keypoint_options", flag="--keypoints-set")
    parser.add_argument("--joints", help="TRC file of joints to carry as landmarks (default: the capture's single *.trc, else the single one in "
                        "Pose2Sim's pose-3d/, else a "
                        "synthetic capture's true joints from its ground_truth.zarr, else the 2D keypoints triangulated)")
    parser.add_argument("--segmenter", metavar="NAME", help="make every camera's masks with this segmenter plugin, e.g. onnx-semantic with "
                        "a person-segmentation model (`mmcsplat plugins --show segmenter:NAME`), instead of from keypoints, plates or motion")
    add_settings(parser, "a parameter of the --segmenter, e.g. model=person.onnx", dest="segmenter_options", flag="--segmenter-set")
    parser.add_argument("--config", default=DEFAULT_CONFIG, help=f"configuration to fit with (default: {DEFAULT_CONFIG})")
    add_settings(parser, "override a configuration value (repeatable)")
    add_settings(parser, "a parameter of the capture's reader (`mmcsplat plugins --show reader:NAME`), as `mmcsplat ingest --set` takes "
                 "it: size_mismatch=crop for videos coded larger than calibrated, camera_map=order, trial=vid01 for one of several trials", dest="reader_options", flag="--reader-set")
    parser.add_argument("--backend", help="renderer backend by name, e.g. torch-cuda on a GPU (default: the configuration's [renderer]); "
                        "the later steps render with it too")
    parser.add_argument("--track-iterations", type=iterations_value, default=AUTO_STEPS, metavar="N",
                        help=f"iterations per frame of the iterative method, or auto (the default): {STEPS_PER_SECOND:g} a second of "
                        f"video and {FEWEST_STEPS} at least (50 at 60 fps, 100 at 30 fps), since frames further apart leave a "
                        "limb further to reach")
    parser.add_argument("--track-means-lr", type=float, default=TRACK_MEANS_LR, metavar="RATE",
                        help=f"learning rate of the means while tracking, times the scene scale (default {TRACK_MEANS_LR:g}: ten times the fit's)")
    parser.add_argument("--track-parts", type=float, default=TRACK_LAMBDA_PARTS, metavar="WEIGHT",
                        help=f"weight of the length prior within body parts, found from the joints' first frame (default {TRACK_LAMBDA_PARTS:g}; "
                        "0: off; none where the joints name no shoulders and hips at the fitted frame)")
    parser.add_argument("--track-flow-gain", type=float, default=TRACK_FLOW_GAIN, metavar="GAIN",
                        help=f"the optical flow's lifted displacement times this starts each tracked frame (default {TRACK_FLOW_GAIN:g}: "
                        "the flow reports about three quarters of a real limb's motion, and the fit does not close the gap; 1: as measured)")
    parser.add_argument("--track-keypoints", type=float, default=0.0, metavar="WEIGHT",
                        help="weight of keypoint guidance: the Gaussians carrying each keypoint pulled towards the training cameras' 2D "
                        "keypoints while tracking (default 0: off, since infants are where detectors fail; 1 for an adult with "
                        "good detections: docs/real-data.md). Their 2D errors then no longer test the tracks; a held-out camera's do")


def iterations_value(text: str) -> int | str:
    """A whole number of steps ≥ 0, or ``auto`` (an argparse type; :func:`mmcsplat.training.frame_steps.checked_steps`)."""
    from mmcsplat.training.frame_steps import AUTO_STEPS, checked_steps

    word = text.strip().lower()
    try:
        return checked_steps(word if word == AUTO_STEPS else int(word))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of steps (0 or more) or {AUTO_STEPS!r}, got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    from mmcsplat.jobs.capture import CaptureSettings, run_capture, summary

    frames = (args.frames.start, args.frames.stop, args.frames.step) if args.frames else (None, None, None)
    settings = CaptureSettings(calibration=args.calibration, units=args.units, scale=args.scale, frames=frames, cameras=args.cameras or (),
                               holdout=args.holdout or (),
                               keypoints=args.keypoints, keypoint_options=args.keypoint_options, joints=args.joints, config=args.config, overrides=args.overrides,
                               reader_options=args.reader_options,
                               track_iterations=args.track_iterations, track_means_lr=args.track_means_lr,
                               track_lambda_parts=args.track_parts, track_flow_gain=args.track_flow_gain,
                               track_keypoints=args.track_keypoints, backend=args.backend, segmenter=args.segmenter,
                               segmenter_options=args.segmenter_options)
    print(summary(run_capture(args.capture, args.out, settings, progress=not args.no_progress)))
    return 0
