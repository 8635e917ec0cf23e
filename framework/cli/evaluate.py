"""Evaluate a fit run (or every fold of one) on its held-out cameras; writes RUN/metrics.json.

Besides the scores it records the share of opacity mass outside the masks' visual hull (floaters) and,
per camera, the share of its mask on the other cameras' visual hull (low: wrong extrinsics or mask). A
run with tracks (`mmcsplat track`) also gets tracking errors against ground truth, the held-out masked
PSNR of every frame and a drift report; when no ground-truth point has a Gaussian nearby at the first
tracked frame, the tracking errors are null, `tracking_error` says why and evaluate warns. A run with
landmarks (`mmcsplat landmarks`) gets their lost landmarks (`lost_landmarks`: which, from which frame)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory written by `mmcsplat fit`")
    parser.add_argument("--backend", help="renderer backend to render with (default: the one that fitted)")
    parser.add_argument("--ground-truth", type=Path, metavar="PATH",
                        help="ground truth of a tracked run (a zarr group with surface_points [T, P, 3]; default: "
                             "ground_truth.zarr beside the session's source capture, as `mmcsplat synth` writes)")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.analysis.lost_landmarks import lost_line
    from mmcsplat.pipeline.evaluate import evaluate

    metrics = evaluate(args.run, backend=args.backend, ground_truth=args.ground_truth)
    for warning in metrics.get("warnings", []):
        print(f"mmcsplat evaluate: warning: {args.run}: {warning}", file=sys.stderr)
    if metrics.get("tracking_error"):
        print(f"mmcsplat evaluate: warning: {args.run}: tracking errors not measured: {metrics['tracking_error']}", file=sys.stderr)
    if args.json:
        print(json.dumps(metrics, indent=2))
        return 0
    for key in ("val_masked_psnr", "val_psnr", "val_ssim", "train_masked_psnr", "num_gaussians", "iterations", "wall_s",
                "tracking_median_mm", "tracking_p90_mm", "tracking_2d_median_px", "drift"):
        if key not in metrics:
            continue
        value = metrics.get(key)
        print(f"{key:<22} {value:.3f}" if isinstance(value, float) else f"{key:<22} {value}")
    if "lost_landmarks" in metrics:
        print(f"{'lost_landmarks':<22} {lost_line(metrics['lost_landmarks'])}")
    return 0
