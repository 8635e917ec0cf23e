"""``mmcsplat run`` on a synthetic capture with nothing but its videos, calibration and ground truth (no
plates, no keypoints, no masks it fits on): the masks come from ``parallax``, and the capture's true joints
are carried, hold the body's parts and are scored, as a TRC's would be. docs/real-data.md has the
full-size figures."""

from __future__ import annotations

import json
import shutil
from contextlib import redirect_stdout
from io import StringIO

from mmcsplat.cli import main
from mmcsplat.synthetic import SynthConfig, synthesize


def test_run_carries_and_scores_a_synthetic_captures_true_joints(tmp_path):
    capture = synthesize(tmp_path / "capture", SynthConfig(frames=4, cameras=6, width=128, height=96, seed=0), progress=False).out_dir
    shutil.rmtree(capture / "plates")  # nothing but videos, calibration and the ground truth
    out = tmp_path / "out"
    with redirect_stdout(StringIO()) as printed:
        assert main(["run", str(capture), "--out", str(out), "--set", "fit.iterations=60", "--track-iterations", "5", "--no-progress"]) == 0
    truth = str((capture / "ground_truth.zarr").resolve())
    assert "joints: median 3D error" in printed.getvalue() and f"against the synthetic joints {truth}" in printed.getvalue()
    assert json.loads((out / "masks.json").read_text())["masks"] == "parallax"
    track = json.loads((out / "run" / "track.json").read_text())
    assert track["params"]["skeleton"] == {"name": "synthetic", "path": truth}
    assert "elbow_left–wrist_left" in track["summary"]["body_parts"]["parts"]
    info = json.loads((out / "run" / "landmarks.json").read_text())
    assert info["source"] == "synthetic" and len(info["names"]) == 14 and not info["unbound"]
    # A few centimetres at worst at this size and with these few steps; the full-size run is at 2 mm (docs/real-data.md).
    assert 0 < info["accuracy_3d"]["median_mm"] < 30
