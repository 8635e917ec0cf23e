"""Evaluate a fit run (or every fold of one) on its held-out cameras; writes RUN/metrics.json."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory written by `mmcsplat fit`")
    parser.add_argument("--backend", help="renderer backend to render with (default: the one that fitted)")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON")


def run(args: argparse.Namespace) -> int:
    from ..evaluate import evaluate

    metrics = evaluate(args.run, backend=args.backend)
    if args.json:
        print(json.dumps(metrics, indent=2))
        return 0
    for key in ("val_masked_psnr", "val_psnr", "val_ssim", "train_masked_psnr", "num_gaussians", "iterations", "wall_s"):
        value = metrics.get(key)
        print(f"{key:<18} {value:.3f}" if isinstance(value, float) else f"{key:<18} {value}")
    return 0
