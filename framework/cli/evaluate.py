"""Evaluate a fit run (or every fold of one) on its held-out cameras; writes RUN/metrics.json.

Besides the scores it records the share of opacity mass outside the masks' visual hull (floaters) and,
per camera, the share of its mask on the other cameras' visual hull (low: wrong extrinsics or mask). A
held-out camera without a mask is scored inside the training cameras' visual hull as it projects there,
at the fitted frame and at every tracked frame; where that hull covers more than 80 % of the image it is
scored on the full image only, and a warning says why. A run with tracks (`mmcsplat track`) also gets
tracking errors against ground truth, the held-out scores of every frame (the table shows their mean
beside the fitted frame's) and a drift report saying how many Gaussians left the subject and since which
frame; when no ground-truth point has a Gaussian nearby at the first tracked frame, the tracking errors
are null, `tracking_error` says why and evaluate warns. A run with landmarks (`mmcsplat landmarks`) gets
their lost landmarks (`lost_landmarks`: which, from which frame). Metric plugins beyond PSNR and SSIM —
the run's configuration's `[[metric]]` tables and each `--metric NAME` — score every camera on the whole
image and inside its mask (`val_NAME`, `val_masked_NAME`, `train_…`; per camera `NAME`, `masked_NAME`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from mmcsplat.cli.options import add_allow_incomplete

#: The console table's rows; those with a ``tracked_`` counterpart show the tracked frames' mean beside
#: the fitted frame's.
ROWS = ("val_masked_psnr", "val_psnr", "val_ssim", "train_masked_psnr", "num_gaussians", "iterations", "wall_s",
        "tracking_median_mm", "tracking_p90_mm", "tracking_2d_median_px", "drift_summary")



def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory written by `mmcsplat fit`")
    parser.add_argument("--backend", help="renderer backend to render with (default: the one that fitted)")
    parser.add_argument("--ground-truth", type=Path, metavar="PATH",
                        help="ground truth of a tracked run (a zarr group with surface_points [T, P, 3]; default: "
                             "ground_truth.zarr beside the session's source capture, as `mmcsplat synth` writes)")
    parser.add_argument("--metric", action="append", default=[], metavar="NAME",
                        help="also score with this metric plugin (`mmcsplat plugins metric`), at its defaults; repeatable "
                             "(a configuration's [[metric]] tables choose them with parameters)")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON")
    add_allow_incomplete(parser)


def _cell(value: Any) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def table(metrics: dict[str, Any]) -> list[str]:
    """The console table of ``metrics``: one row per :data:`ROWS` key present; with tracks, a column of
    the tracked frames' means beside the fitted frame's; then the metric plugins' rows."""
    tracked = any(f"tracked_{key}" in metrics for key in ROWS)
    lines = [f"{'':<22} {'fitted frame':<14} tracked frames (mean)"] if tracked else []
    chosen = [f"{split}_{masked}{name}" for name in metrics.get("metrics", []) for split in ("val", "train") for masked in ("masked_", "")]
    for key in (*ROWS, *chosen):
        if key not in metrics:
            continue
        cells = [_cell(metrics[key])]
        if f"tracked_{key}" in metrics:
            cells = [f"{cells[0]:<14}", _cell(metrics[f"tracked_{key}"])]
        lines.append(f"{key:<22} {' '.join(cells)}")
    return lines


def run(args: argparse.Namespace) -> int:
    from mmcsplat.analysis.lost_landmarks import lost_line
    from mmcsplat.pipeline.evaluate import evaluate

    metrics = evaluate(args.run, backend=args.backend, ground_truth=args.ground_truth, allow_incomplete=args.allow_incomplete,
                       progress=not args.no_progress, metrics=args.metric)
    if metrics.get("incomplete"):
        print(f"mmcsplat evaluate: warning: {args.run} is unfinished: its metrics are labelled incomplete", file=sys.stderr)
    for warning in metrics.get("warnings", []):
        print(f"mmcsplat evaluate: warning: {args.run}: {warning}", file=sys.stderr)
    if metrics.get("tracking_error"):
        print(f"mmcsplat evaluate: warning: {args.run}: tracking errors not measured: {metrics['tracking_error']}", file=sys.stderr)
    if args.json:
        print(json.dumps(metrics, indent=2))
        return 0
    print("\n".join(table(metrics)))
    if "lost_landmarks" in metrics:
        print(f"{'lost_landmarks':<22} {lost_line(metrics['lost_landmarks'])}")
    return 0
