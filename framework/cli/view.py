"""Look at a run in the browser: its Gaussians over the tracked frames, the cameras and trails (viser).

Serves an interactive 3D viewer on HOST:PORT (default http://127.0.0.1:8080) and prints its URL; open it in
a browser. A frame slider and a play box step through the run's frames (a run without tracks shows its
first-frame fit); every session camera is drawn as a frustum with its first image (held-out ones in
orange); "view from" puts the browser's camera at one of them (the held-out one to begin with); "points"
draws centres instead of splats; "trails" draws the last 10 frames of 2 % of the subject's Gaussians.
Ctrl-C stops the server.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, help="run directory of `mmcsplat fit` (with RUN/tracks.zarr after `mmcsplat track`)")
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1, this machine only; 0.0.0.0 for the network)")
    parser.add_argument("--port", type=int, default=8080, help="port to serve on (default 8080; the next free one when taken)")
    parser.add_argument("--fps", type=float, default=10.0, help="frames per second of the play box (default 10)")


def run(args: argparse.Namespace) -> int:
    from mmcsplat.cli.main import CommandError, Terminated
    from mmcsplat.outputs.viewer import RunViewer

    if not args.fps > 0:
        raise CommandError(f"--fps must be > 0, got {args.fps}")
    if not 0 < args.port < 65536:
        raise CommandError(f"--port must be in 1–65535, got {args.port}")
    viewer = RunViewer(args.run, host=args.host, port=args.port, fps=args.fps)
    frames = viewer.states.num_frames
    print(f"{args.run}: {frames} frame(s), {len(viewer.cameras)} cameras — viewer at {viewer.url} (Ctrl-C stops it)", flush=True)
    try:
        viewer.serve_forever()
    except Terminated:
        print("viewer stopped (SIGTERM)")
        return 143
    except KeyboardInterrupt:
        pass
    print("viewer stopped")  # Ctrl-C is how a viewer ends: a normal exit
    return 0
