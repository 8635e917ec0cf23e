"""Run every variant of a study over several seeds and report how often it fails.

STUDY is a study TOML file or a built-in study by name, as for `mmcsplat compare` (docs/studies.md); its
seeds are replaced by 0 … N-1 and its cells run (and resume) the same way. Each run is classified:
diverged (NaN/Inf, loss blow-up), failed (another error), floaters (opacity mass outside the masks'
visual hull), calibration (a camera's mask off the other cameras' visual hull), overfit (training views
far above the held-out view), drift (tracked runs) or warned (too few cameras, a camera that never sees
the subject). Writes OUT/stability.json, stability.csv and stability.md (besides the study's results)
and prints the table of fractions and held-out PSNR spread per variant. The thresholds and how they were
measured: docs/studies.md, "Stability".
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from mmcsplat.studies.stability import DEFAULT_SEEDS

    parser.add_argument("study", help="a study TOML file, or the name of a built-in study (paper-ablation, dynamics)")
    parser.add_argument("--out", required=True, type=Path, help="study directory (created; what is done there is reused)")
    parser.add_argument("--seeds", type=int, default=DEFAULT_SEEDS, metavar="N", help=f"seeds per cell, 0 … N-1 (default {DEFAULT_SEEDS})")
    parser.add_argument("--executor", choices=("local", "ray"), default="local",
                        help="local: a pool of processes on this machine (default); ray: Ray tasks, as for compare")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="local: worker processes (default 1; 0 runs the cells in this process); ray: tasks in flight (default: all)")
    parser.add_argument("--ray-address", metavar="ADDRESS", help="the Ray cluster to join (default: RAY_ADDRESS, else a local instance)")
    parser.add_argument("--retry-failed", action="store_true", help="run the cells that failed or diverged in an earlier pass again")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.studies.spec import load_study
    from mmcsplat.studies.stability import run_stability, stability_table

    study = load_study(args.study)
    result = run_stability(study, args.out, args.seeds, executor=args.executor, workers=args.workers, retry_failed=args.retry_failed,
                           ray_address=args.ray_address, progress=not args.no_progress)
    print(stability_table(result.rows))
    print(f"study {study.name}: {len(result.run.rows)} runs over {args.seeds} seeds, {result.run.ran} run now, "
          f"{result.run.reused} reused; report in {args.out / 'stability.md'}")
    return 0
