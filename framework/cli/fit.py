"""Fit the first frame of a session: Gaussians optimised on the training cameras (resumes a killed run).

With --folds, one fit per held-out camera (leave-one-camera-out) into RUN/<camera>/.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="session store (path or URL) written by `mmcsplat ingest`")
    parser.add_argument("--config", required=True, help="a built-in configuration name (`mmcsplat configs`) or a TOML file")
    parser.add_argument("--out", required=True, type=Path, help="run directory (a checkpoint there is resumed)")
    parser.add_argument("--backend", help="renderer backend by name, overriding the configuration's [renderer]")
    parser.add_argument("--holdout", help="comma-separated held-out cameras (default: the session's own)")
    parser.add_argument("--folds", help="comma-separated cameras: one fit per camera held out, into OUT/<camera>/")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a configuration value, e.g. --set fit.iterations=500 (repeatable)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _split(text: str | None) -> list[str] | None:
    return None if text is None else [name.strip() for name in text.split(",") if name.strip()]


def run(args: argparse.Namespace) -> int:
    from mmcsplat.configuration.config import load_config
    from mmcsplat.pipeline.fit import FirstFrameFit
    from mmcsplat.storage.session import SessionReader

    config = load_config(args.config, args.overrides)
    session = SessionReader(args.session)
    folds = _split(args.folds)
    plan = [(args.out / camera, [camera]) for camera in folds] if folds else [(args.out, _split(args.holdout))]
    for out, holdout in plan:
        fit = FirstFrameFit(session, config, out, holdout=holdout, backend=args.backend, progress=not args.no_progress)
        info = fit.run()
        resumed = f", resumed from iteration {info.resumed_from}" if info.resumed_from is not None else ""
        print(f"{out}: {info.iterations} iterations{resumed}, {info.num_gaussians} Gaussians, {info.wall_s:.1f} s "
              f"(held out: {', '.join(info.heldout_cameras) or 'none'})")
    return 0
