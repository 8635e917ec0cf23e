"""Run a study: variants × sessions × folds × seeds, each cell once; tables and charts of the results.

STUDY is a study TOML file or a built-in study by name (paper-ablation, dynamics); docs/studies.md
describes the format. Every cell is keyed by a hash of its resolved configuration and stored in
OUT/cells/KEY/, so a rerun skips the cells already done and resumes a cut-off fit from its checkpoint.
Writes OUT/results.csv, results.json, results.md and OUT/charts/ (PNG and SVG).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", help="a study TOML file, or the name of a built-in study (paper-ablation, dynamics)")
    parser.add_argument("--out", required=True, type=Path, help="study directory (created; what is done there is reused)")
    parser.add_argument("--executor", choices=("local", "ray"), default="local",
                        help="local: a pool of processes on this machine (default); ray: Ray tasks (extra 'distributed'), "
                             "on a cluster when RAY_ADDRESS or --ray-address names one (OUT must be shared storage)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="local: worker processes (default 1; 0 runs the cells in this process); ray: tasks in flight (default: all)")
    parser.add_argument("--ray-address", metavar="ADDRESS", help="the Ray cluster to join (default: RAY_ADDRESS, else a local instance)")
    parser.add_argument("--retry-failed", action="store_true", help="run the cells that failed in an earlier pass again")
    parser.add_argument("--dry-run", action="store_true", help="list the cells and whether each is done, run nothing")
    parser.add_argument("--publish", type=Path, metavar="FILE.md",
                        help="also put the results into FILE.md between this study's markers, charts in FILE_FOLDER/results/NAME/")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.studies.cells import CellOutcome
    from mmcsplat.studies.results import SMALLEST_WITHIN_DB
    from mmcsplat.studies.runner import CELLS_DIR, publish, run_study
    from mmcsplat.studies.spec import expand, load_study

    study = load_study(args.study)
    if args.dry_run:
        for cell in expand(study, args.out):
            outcome = CellOutcome.read(args.out / CELLS_DIR / cell.spec.key)
            state = outcome.status if outcome else "partial" if (args.out / CELLS_DIR / cell.spec.key).exists() else "to run"
            print(f"{cell.spec.key}  {state:<8}  {cell.variant} | {cell.session} | fold {cell.fold} | seed {cell.seed} | {cell.backend}")
        return 0
    result = run_study(study, args.out, executor=args.executor, workers=args.workers, retry_failed=args.retry_failed,
                       ray_address=args.ray_address, progress=not args.no_progress)
    if args.publish:
        publish(result, args.publish, f"mmcsplat compare {args.study} --out {args.out} --publish {args.publish}")
    print(f"study {study.name}: {len(result.rows)} cells, {result.ran} run now, {result.reused} reused; results in {args.out / 'results.md'}")
    if result.findings.best:
        print(f"best held-out masked PSNR: {result.findings.best}; smallest model within {SMALLEST_WITHIN_DB} dB: {result.findings.smallest_within}")
    for row in result.failed:
        print(f"failed: {row.cell.variant} | {row.cell.session} | fold {row.cell.fold} | seed {row.cell.seed}: {row.outcome.error}")
    return 1 if result.failed else 0
