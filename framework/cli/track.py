"""Track a first-frame fit through its session with a dynamics method; writes RUN/tracks.zarr.

The configuration is the one RUN was fitted with unless --config names another; its [dynamics] table
(or --dynamics) chooses the method, `iterative` when neither names one (the built-in configurations are
first-frame ones and have none; the summary line says so). RUN/track.json records the method, its
parameters and timings.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmcsplat.cli.options import add_frames, add_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory of a completed `mmcsplat fit`")
    parser.add_argument("--config", help="a built-in configuration name or TOML file (default: the run's own)")
    parser.add_argument("--dynamics", metavar="NAME", help="dynamics method by name, instead of the configuration's [dynamics] (default: its method, else iterative)")
    add_settings(parser, "override a configuration value, e.g. --set dynamics.iterations=300 (repeatable)")
    parser.add_argument("--backend", help="renderer backend by name (default: the one that fitted)")
    add_frames(parser, "session frames to track, from the fitted one: :STOP tracks up to frame STOP − 1 (default: all)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing RUN/tracks.zarr (new tracks always remove what was made before them: metrics.json, landmarks, movement, renders/, report.html)")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.pipeline.track import track_run

    record = track_run(args.run, config=args.config, overrides=args.overrides, dynamics=args.dynamics,
                       backend=args.backend, progress=not args.no_progress, overwrite=args.overwrite, frames=args.frames)
    start, stop = record["frames"]
    summary = record["summary"] if isinstance(record["summary"], dict) else {}
    resumed, steps = summary.get("resumed_from"), summary.get("iterations_per_frame")
    default = " (the default: the configuration names no dynamics method)" if record["method_default"] else ""
    print(f"{args.run}: tracked frames {start}–{stop - 1} with {record['method']}{default}{f' at {steps} steps a frame' if steps else ''} "
          f"in {record['wall_s']:.1f} s "
          f"({record['wall_s_per_frame']:.2f} s per frame){f', resumed from iteration {resumed}' if resumed is not None else ''}")
    if record["removed"]:
        print(f"{args.run}: removed {', '.join(record['removed'])}: made before these tracks (evaluate, landmarks, render and report "
              "make them again)")
    return 0
