"""A dynamics method from a third-party package (tests/thirdparty/dynamics), written on the public API
alone and registered by entry point, runs through `mmcsplat track` like a built-in."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from fitting_scene import moved, subject, write_fitted_run, write_session

from mmcsplat.storage.tracks import TrackReader

PLUGIN_DIR = Path(__file__).parent / "thirdparty" / "dynamics"
FRAMES = 4


def mmcsplat(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(PLUGIN_DIR), os.environ.get("PYTHONPATH", "")]))
    code = f"import sys; from mmcsplat.cli import main; sys.exit(main({list(args)!r}))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)


def test_constant_velocity_plugin_tracks_through_the_cli(tmp_path):
    session = write_session(tmp_path / "session.zarr", frames=FRAMES)
    run = write_fitted_run(tmp_path / "run", session)

    shown = mmcsplat("plugins", "--show", "constant-velocity")
    assert shown.returncode == 0, shown.stderr
    assert "mmcsplat-constant-velocity" in shown.stdout and "iterations" in shown.stdout

    refused = mmcsplat("track", str(run), "--dynamics", "constant-velocity", "--set", "dynamics.lr=-1", "--no-progress")
    assert refused.returncode == 2 and "dynamics 'constant-velocity': lr must be > 0" in refused.stderr

    done = mmcsplat("track", str(run), "--dynamics", "constant-velocity", "--set", "dynamics.iterations=30",
                    "--set", "dynamics.lr=0.002", "--no-progress")
    assert done.returncode == 0, done.stderr
    record = json.loads((run / "track.json").read_text())
    assert record["summary"]["iterations_per_frame"] == 30
    curve = (run / "curves.csv").read_text().splitlines()  # logged through TrackingContext.curve
    assert len(curve) == FRAMES and curve[1].startswith("track,30,1,")
    tracks = TrackReader(run)
    assert tracks.method == "constant-velocity" and tracks.num_frames == FRAMES
    # The subject slides 5 mm per frame along x (its bent half moves more): one translation follows the slide.
    truth = [moved(subject(), t).means.numpy().mean(axis=0) for t in range(FRAMES)]
    shift = tracks.means(FRAMES - 1).mean(axis=0) - tracks.means(0).mean(axis=0)
    true_shift = truth[-1] - truth[0]
    assert abs(shift[0] - true_shift[0]) < 0.5 * abs(true_shift[0]), (shift, true_shift)
    assert np.abs(shift[1:]).max() < 0.5 * abs(true_shift[0])


def test_the_plugin_imports_only_the_public_api():
    import ast

    public = {"plugin_api", "scene", "storage", "training"}
    for path in PLUGIN_DIR.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mmcsplat"):
                parts = node.module.split(".")
                assert len(parts) == 1 or parts[1] in public, f"{path.name} imports {node.module}"
                assert not any(alias.name.startswith("_") for alias in node.names), f"{path.name} imports a private name"
