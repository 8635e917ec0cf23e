"""Estimate clean plates from the sequence itself, for a session recorded without an empty scene.

Each camera's plate is the per-pixel temporal median of frames spread through its recording, the subject
left out where the session has masks (segment first when you can). The plates are stored in the session,
marked as estimated, and fits with `fit.background = "plate"` use them like recorded ones. Cameras that
already have a plate are left alone unless --replace.
"""

from __future__ import annotations

import argparse

from mmcsplat.cli.options import add_names


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="the session to update (a path or URL)")
    add_names(parser, "--cameras", "estimate only these cameras' plates (default: all)")
    parser.add_argument("--num-samples", type=int, default=25, metavar="N", help="frames sampled per camera for the median (default: 25)")
    parser.add_argument("--replace", action="store_true", help="also replace plates the session already has (recorded ones included)")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.pipeline.plates import estimate_plates

    estimates = estimate_plates(args.session, args.cameras, args.num_samples, args.replace, progress=not args.no_progress)
    if not estimates:
        print(f"{args.session}: every selected camera already has a plate (--replace to estimate them anew)")
    for estimate in estimates:
        masks = "subject masked out" if estimate.masked else "no masks: the subject must move for the median to skip it"
        print(f"{estimate.camera}: plate from {estimate.samples} frames ({masks}); stable background {estimate.stable_share:.1%}"
              f"{f', never uncovered (inpainted) {estimate.uncovered_share:.1%}' if estimate.masked else ''}")
    return 0
