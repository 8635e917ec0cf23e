"""The real Pose2Sim demo (../shared/data/pose2sim_demo: 4 cameras, no plates, no masks) end to end with
the one command, at a small scale: ingest, skeleton masks from its 2D keypoints, plates estimated with
the subject masked out, masks refined against them, a fit whose start region is sized from the masks, a
short track, its triangulated joints carried and scored in 3D and against the keypoints in every camera,
the renders and the report; a rerun redoes nothing. docs/results.md has the full-length figures."""

from __future__ import annotations

import json
import re
from contextlib import redirect_stdout
from io import StringIO
from pathlib import Path

import numpy as np
import pytest

from mmcsplat.cli import main
from mmcsplat.jobs.capture import TRACK_FLOW_GAIN, TRACK_LAMBDA_PARTS, TRACK_MEANS_LR
from mmcsplat.storage.landmark_formats import read_landmark_csv
from mmcsplat.storage.session import SessionReader

POSE2SIM = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pose2sim_demo"


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared real data not found at {POSE2SIM}")
def test_pose2sim_demo_runs_with_one_command(tmp_path):
    out = tmp_path / "out"
    command = ["run", str(POSE2SIM), "--out", str(out), "--calibration", str(POSE2SIM / "Calib_qualisys.toml"), "--frames", "0:4",
               "--scale", "0.125", "--holdout", "cam_04", "--set", "fit.iterations=60", "--track-iterations", "5", "--no-progress"]
    with redirect_stdout(StringIO()) as printed:
        assert main(command) == 0
    assert "mmcsplat run finished" in printed.getvalue() and "joints: median 3D error" in printed.getvalue()
    assert "for a body of fixed bones placed nearest it, the reference's floor" in printed.getvalue()
    assert f"run: keypoints: openpose from {POSE2SIM / 'pose_2d'}" in printed.getvalue()  # found in the capture, and said which
    reader = SessionReader(out / "session.zarr")
    coverage = [reader.frame(0, name).mask.mean() for name in reader.camera_names]
    assert all(0.02 < share < 0.2 for share in coverage), coverage  # a standing adult in a portrait view
    assert all(reader.plate_source(name)["kind"] == "estimated" for name in reader.camera_names)
    run = out / "run"
    # The start cube was sized from the masks' hull: the configuration's 0.75 m holds too little of an adult.
    visual_hull = json.loads((run / "run.json").read_text())["config_values"]["initializer"][0]
    assert visual_hull["name"] == "visual-hull" and visual_hull["half_size"] > 0.75
    # Tracked at run's means learning rate, not the fit's (a fast limb is out of reach of a few dozen steps at that), from
    # the flow's prediction at run's gain, with the body's parts from the capture's joints held at their lengths.
    track = json.loads((run / "track.json").read_text())
    assert track["params"] == {"iterations": 5, "means_lr": TRACK_MEANS_LR, "flow_gain": TRACK_FLOW_GAIN, "lambda_parts": TRACK_LAMBDA_PARTS,
                               "skeleton": {"name": "trc", "path": str(POSE2SIM / "joints_3d.trc")}}
    parts = track["summary"]["body_parts"]
    assert "LElbow–LWrist" in parts["parts"] and "RHip–RKnee" in parts["parts"] and parts["pairs"] > 0
    names, frames, _, positions, _ = read_landmark_csv(run / "landmarks.csv")
    assert len(names) == 21 and frames.tolist() == [0, 1, 2, 3]
    info = json.loads((run / "landmarks.json").read_text())
    assert len(info["unbound"]) < 10 and info["accuracy_3d"]["pairs"] > 0
    scores = info["accuracy_2d"]
    assert sorted(scores) == ["cam_01", "cam_02", "cam_03", "cam_04"] and scores["cam_04"]["heldout"]
    # The recorded video is 8× the stored images here: errors are quoted in its pixels too.
    assert scores["cam_04"]["source_scale"] == pytest.approx(8.0, rel=0.01)
    assert all(np.isfinite(s["carried_median_source_px"]) and s["reference_median_source_px"] < 40 for s in scores.values())
    # The TRC's bones change length: the nearest body of fixed bones lies off it, and is scored in 2D too.
    floor = info["reference_floor"]
    assert "LHip-LKnee" in floor["bones"] and 0 < floor["median_mm"] < 60 and np.isfinite(floor["carried_median_mm"])
    assert all(np.isfinite(s["floor_median_source_px"]) for s in scores.values())
    report = (run / "report.html").read_text()
    assert (run / "renders" / "landmarks_cam_04.mp4").exists() and "<h2>Movement</h2>" in report and "floor: a body of fixed bones" in report
    movement = json.loads((run / "movement.json").read_text())  # Pose2Sim's BODY_25 names give every joint angle
    assert movement["joint_angles_left_out"] == {} and (run / "movement.csv").exists()
    with redirect_stdout(StringIO()) as again:
        assert main(command) == 0
    steps = re.findall(r"^\[run\] .*", again.getvalue(), flags=re.M)
    assert len(steps) > 5 and all("already done" in line for line in steps)


@pytest.mark.skipif(not POSE2SIM.is_dir(), reason=f"shared real data not found at {POSE2SIM}")
def test_a_capture_with_keypoints_and_no_trc_carries_the_keypoints_own_joints(tmp_path):
    """What most captures bring: videos, a calibration and 2D detections, no 3D joints. The detections'
    triangulation is bound, carried and scored, and sizes the body's parts."""
    capture = tmp_path / "capture"
    capture.mkdir()
    for name in ("videos", "pose_2d", "Calib_qualisys.toml"):
        (capture / name).symlink_to(POSE2SIM / name)
    out = tmp_path / "out"
    with redirect_stdout(StringIO()) as printed:
        assert main(["run", str(capture), "--out", str(out), "--frames", "0:3", "--scale", "0.125", "--set", "fit.iterations=30",
                     "--track-iterations", "3", "--no-progress"]) == 0
    assert "run: joints: the keypoints' own triangulation (the capture has no TRC)" in printed.getvalue()
    assert f"against the OpenPose keypoints {POSE2SIM / 'pose_2d'} (BODY_25B), triangulated" in printed.getvalue()
    run = out / "run"
    track = json.loads((run / "track.json").read_text())
    assert track["params"]["skeleton"] == {"name": "openpose", "folder": str(POSE2SIM / "pose_2d")}
    assert "LElbow–LWrist" in track["summary"]["body_parts"]["parts"]
    info = json.loads((run / "landmarks.json").read_text())
    assert "LKnee" in info["names"] and "Head" in info["names"] and info["accuracy_3d"]["pairs"] > 0
    assert all(np.isfinite(score["carried_median_source_px"]) for score in info["accuracy_2d"].values())
