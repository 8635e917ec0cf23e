"""The real Pose2Sim demo (../shared/data/pose2sim_demo: 4 cameras, no plates, no masks) end to end at a
small scale — ingest, skeleton masks from its 2D keypoints, plates estimated with the subject masked out,
masks refined against them, a short fit and track, then its triangulated joints carried and scored in
3D and against the keypoints in every camera. docs/results.md has the full-length figures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mmcsplat.cli import main
from mmcsplat.storage.landmark_files import read_landmark_csv
from mmcsplat.storage.session import SessionReader

POSE2SIM = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pose2sim_demo"
KEYPOINTS = f'source={{name="openpose", folder="{POSE2SIM / "pose_2d"}"}}'
FIT = """[fit]
iterations = 60
checkpoint_every = 60
lambda_seg = 0.3
background = "plate"

[renderer]
name = "torch-cpu"

[[initializer]]
name = "visual-hull"
num_points = 3000
half_size = 1.25

[[initializer]]
name = "masked"
radius = 2.0
"""


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared real data not found at {POSE2SIM}")
def test_pose2sim_demo_end_to_end_small(tmp_path):
    session = tmp_path / "p2s.zarr"
    assert main(["ingest", str(POSE2SIM), str(session), "--calibration", str(POSE2SIM / "Calib_qualisys.toml"), "--frames", "0:4",
                 "--scale", "0.125", "--holdout", "cam_04", "--no-progress"]) == 0
    assert main(["segment", str(session), "--segmenter", "keypoints", "--set", KEYPOINTS, "--no-progress"]) == 0
    assert main(["plates", str(session), "--no-progress"]) == 0
    assert main(["segment", str(session), "--segmenter", "keypoints", "--set", KEYPOINTS, "--set", "refine=plate", "--no-progress"]) == 0
    reader = SessionReader(session)
    coverage = [reader.frame(0, name).mask.mean() for name in reader.camera_names]
    assert all(0.02 < share < 0.2 for share in coverage), coverage  # a standing adult in a portrait view
    assert all(reader.plate_source(name)["kind"] == "estimated" for name in reader.camera_names)
    (tmp_path / "fit.toml").write_text(FIT)
    run = tmp_path / "run"
    assert main(["fit", str(session), "--config", str(tmp_path / "fit.toml"), "--out", str(run), "--no-progress"]) == 0
    assert main(["track", str(run), "--dynamics", "iterative", "--set", "dynamics.iterations=5", "--no-progress"]) == 0
    assert main(["landmarks", str(run), "--source", "trc", "--set", f"path={POSE2SIM / 'joints_3d.trc'}",
                 "--keypoints", "openpose", "--keypoints-set", f"folder={POSE2SIM / 'pose_2d'}"]) == 0
    names, frames, _, positions, _ = read_landmark_csv(run / "landmarks.csv")
    assert len(names) == 21 and frames.tolist() == [0, 1, 2, 3]
    info = json.loads((run / "landmarks.json").read_text())
    assert len(info["unbound"]) < 10 and info["accuracy_3d"]["pairs"] > 0
    scores = info["accuracy_2d"]
    assert sorted(scores) == ["cam_01", "cam_02", "cam_03", "cam_04"] and scores["cam_04"]["heldout"]
    # The recorded video is 8× the stored images here: errors are quoted in its pixels too.
    assert scores["cam_04"]["source_scale"] == pytest.approx(8.0, rel=0.01)
    assert all(np.isfinite(s["carried_median_source_px"]) and s["reference_median_source_px"] < 40 for s in scores.values())
