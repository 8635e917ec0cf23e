"""Run the main job on the built-in synthetic infant capture, end to end.

Synthesizes the capture, ingests and segments it, fits the first frame, tracks the sequence (the
configuration's [dynamics] table, else the iterative method with --track-iterations per frame), evaluates
on the held-out camera (masked PSNR; tracking errors against the capture's ground truth), renders the
tracking figure and a novel-view path, and writes the HTML report; then lists every output and each
step's time. Steps already done in OUT are reused, so a rerun resumes where the last one stopped.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mmcsplat.cli.options import add_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, type=Path, help="output directory (created; reused steps are skipped)")
    parser.add_argument("--config", default="masked-plate", help="configuration to fit and track with (default: masked-plate)")
    parser.add_argument("--backend", help="renderer backend (default: the configuration's)")
    add_settings(parser, "override a configuration value (repeatable)")
    parser.add_argument("--num-frames", type=int, default=30, metavar="N", help="frames to synthesize (default 30)")
    parser.add_argument("--width", type=int, default=256, help="image width of the synthetic capture in pixels (default 256)")
    parser.add_argument("--height", type=int, default=192, help="image height of the synthetic capture in pixels (default 192)")
    parser.add_argument("--track-iterations", type=int, metavar="N",
                        help="iterations per frame of the iterative method (default: the configuration's [dynamics] "
                             "table, else 50: the demo's infant moves slowly)")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.jobs.demo import DemoSettings, run_demo, summary

    settings = DemoSettings(frames=args.num_frames, width=args.width, height=args.height, config=args.config,
                            overrides=args.overrides, backend=args.backend, track_iterations=args.track_iterations)
    print(summary(run_demo(args.out, settings, progress=not args.no_progress)))
    return 0
