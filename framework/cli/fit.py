"""Fit the first frame of a session: Gaussians optimised on the training cameras (resumes a killed run).

With --folds, one fit per held-out camera (leave-one-camera-out) into RUN/<camera>/, the folds listed in
RUN/folds.json first: run again after a kill, each fold resumes from its checkpoint (or starts again
when it had none), and evaluate refuses the run while a fold is missing or unfinished. Start and pruning
regions too small for the subject's visual hull are grown by their initializers to hold it, saying so,
unless --fixed-regions.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mmcsplat.cli.options import add_names, add_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="session store (path or URL) written by `mmcsplat ingest`")
    parser.add_argument("--config", required=True, help="a built-in configuration name (`mmcsplat configs`) or a TOML file")
    parser.add_argument("--out", required=True, type=Path, help="run directory (a checkpoint there is resumed)")
    parser.add_argument("--backend", help="renderer backend by name, overriding the configuration's [renderer]")
    add_names(parser, "--holdout", "held-out cameras (default: the session's own)")
    add_names(parser, "--folds", "one fit per camera held out, into OUT/<camera>/")
    add_settings(parser, "override a configuration value, e.g. --set fit.iterations=500 (repeatable)")
    parser.add_argument("--fixed-regions", action="store_true",
                        help="keep the configuration's start and pruning regions even when the subject's visual hull does not fit "
                             "in them (the fit is then refused), instead of growing them")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.cli.main import CommandError
    from mmcsplat.configuration.config import load_config
    from mmcsplat.pipeline.evaluate import fit_signals
    from mmcsplat.pipeline.fit import FirstFrameFit
    from mmcsplat.storage.folds import write_fold_plan
    from mmcsplat.storage.session import SessionReader, enclosing_session

    if (store := enclosing_session(args.out)) is not None:
        raise CommandError(f"--out {args.out} lies inside the session store {store}: a run is never written into a session; give another --out")
    config = load_config(args.config, args.overrides)
    session = SessionReader(args.session)
    plan = [(args.out / camera, [camera]) for camera in args.folds] if args.folds else [(args.out, args.holdout)]
    if args.folds:
        write_fold_plan(args.out, args.folds)
    for out, holdout in plan:
        fit = FirstFrameFit(session, config, out, holdout=holdout, backend=args.backend, progress=not args.no_progress,
                            grow_regions=not args.fixed_regions)
        for grown in fit.grown_regions:
            print(f"{out}: {grown}")
        info = fit.run()
        resumed = f", resumed from iteration {info.resumed_from}" if info.resumed_from is not None else ""
        print(f"{out}: {info.iterations} iterations{resumed}, {info.num_gaussians} Gaussians, {info.wall_s:.1f} s "
              f"(held out: {', '.join(info.heldout_cameras) or 'none'})")
        for warning in fit_signals(out):  # a fit that "completed" on a cloud of floaters says so
            print(f"mmcsplat fit: warning: {out}: {warning}", file=sys.stderr)
    return 0
