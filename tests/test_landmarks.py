"""mmcsplat landmarks: joints read from a file are bound to the subject's Gaussians, carried through a run's
tracks (here a known rigid motion, so the answer is exact), scored against the file's later frames, left
out when nothing is near them, measured (movement.json and .csv, a knee angle among them), exported to
TRC / CSV / C3D, drawn on a camera and shown in the report."""

from __future__ import annotations

import csv
import json
import warnings

import numpy as np
import pytest
import torch
from fitting_scene import write_fitted_run, write_session
from scipy.spatial.transform import Rotation

from mmcsplat.analysis.movement import flexion
from mmcsplat.cli import main
from mmcsplat.outputs import landmark_export
from mmcsplat.plugins.landmarks.files import CsvLandmarks, TrcLandmarks
from mmcsplat.storage.landmark_formats import read_c3d, read_landmark_csv, read_trc, write_landmark_csv, write_trc
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.tracks import TrackWriter
from mmcsplat.training.fitted_run import FittedRun

FRAMES = 5
NAMES = ("LWrist", "RWrist", "LAnkle", "RAnkle", "LHip", "LKnee", "far")
CARRIED = len(NAMES) - 1  # all but "far"


def motion(t: int) -> tuple[Rotation, np.ndarray]:
    """Frame t's rigid motion of the whole subject: 0.15 rad per frame about z, 1 cm per frame along x."""
    return Rotation.from_euler("z", 0.15 * t), np.array([0.01 * t, 0.0, 0.0])


def tracked_scene(root, provenance: dict | None = None):
    """(a run whose tracks move the subject rigidly, the landmarks file, the true landmarks [T, L, 3]) in
    ``root``; the session's ``provenance`` says which capture frames it took (the file is numbered by them)."""
    session = write_session(root / "session.zarr", frames=FRAMES, provenance=provenance)
    run = write_fitted_run(root / "run", session)
    params = FittedRun.load(run).params
    means, quats = params["means"].double().numpy(), params["quats"].double().numpy()
    with TrackWriter(run, num_frames=FRAMES, static={k: params[k] for k in ("log_scales", "opacity_logits", "color_logits", "seg_logits")},
                     method="rigid", attrs={"first_frame": 0}) as writer:
        for t in range(FRAMES):
            rotation, shift = motion(t)
            turned = (rotation * Rotation.from_quat(quats, scalar_first=True)).as_quat(scalar_first=True)
            writer.write_frame(t, means=torch.as_tensor(rotation.apply(means) + shift, dtype=torch.float32),
                               quats=torch.as_tensor(turned, dtype=torch.float32))
    start = np.array([[0.10, 0.03, 0.0], [-0.10, 0.02, 0.01], [0.05, -0.04, 0.02], [-0.06, -0.03, 0.0],
                      [0.0, -0.06, 0.0], [0.0, -0.01, 0.01], [2.0, 2.0, 2.0]])
    truth = np.stack([motion(t)[0].apply(start) + motion(t)[1] for t in range(FRAMES)])
    reader = SessionReader(session)
    path = root / "joints.csv"
    write_landmark_csv(path, NAMES, reader.capture_frames(np.arange(FRAMES)), reader.frame_times, truth)
    return run, path, truth


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return tracked_scene(tmp_path_factory.mktemp("landmarks"))


def test_landmarks_follow_the_tracks_and_are_scored(scene, capsys):
    run, path, truth = scene
    with pytest.warns(UserWarning, match="landmarks far: no subject Gaussian within 10 cm"):
        assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}"]) == 0
    assert f"{CARRIED} landmarks over 5 frames; left out (no subject Gaussian within 10 cm): far" in capsys.readouterr().out
    names, frames, times, positions, extra = read_landmark_csv(run / "landmarks.csv")
    assert names == NAMES and frames.tolist() == list(range(FRAMES))
    np.testing.assert_allclose(positions[:, :CARRIED], truth[:, :CARRIED], atol=2e-6)  # float32 tracks
    assert np.isnan(positions[:, CARRIED]).all()
    assert np.nanmax(extra["spread_mm"]) < 0.01 and np.nanmin(extra["confidence"]) > 0.99  # rigid: the anchors agree
    info = json.loads((run / "landmarks.json").read_text())
    accuracy = info["accuracy_3d"]
    # Bound from 4 of the 5 frames (the default 7 is cut to leave the last to score), scored on the last alone.
    assert info["bind_frames"] == FRAMES - 1 and accuracy["per_frame_median_mm"][: FRAMES - 1] == [None] * (FRAMES - 1)
    assert accuracy["median_mm"] < 0.01 and accuracy["pairs"] == CARRIED
    assert accuracy["still_moving_median_mm"] > 10 and info["unbound"] == ["far"]


def test_movement_measures_are_written_beside_the_landmarks(scene):
    run, path, truth = scene
    (run / "movement.json").unlink(missing_ok=True)
    with pytest.warns(UserWarning, match="landmarks far"):
        assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}"]) == 0
    movement = json.loads((run / "movement.json").read_text())
    assert movement["frames"] == FRAMES and set(movement["landmarks"]) == set(NAMES)
    assert movement["landmarks"]["far"]["mean_speed_m_s"] is None  # never carried: not measured
    travelled = np.linalg.norm(np.diff(truth[:, 0], axis=0), axis=1).sum()
    assert movement["landmarks"]["LWrist"]["path_length_m"] == pytest.approx(travelled, abs=1e-5)
    knee = movement["joint_angles"]["left_knee_flexion"]  # the rigid motion keeps the leg's bend: one known angle at every frame
    bend = flexion(truth[:, 4], truth[:, 5], truth[:, 2])
    np.testing.assert_allclose(knee["per_frame_deg"], bend, atol=1e-3)
    assert knee["range_deg"] < 1e-3 and knee["frames"] == FRAMES
    angle_error = json.loads((run / "landmarks.json").read_text())["accuracy_joint_angles"]  # against the file's own knee angle
    assert angle_error["median_deg"] < 1e-3 and angle_error["pairs"] == 1  # scored after the 4 frames it was bound from
    assert movement["joint_angles_left_out"]["right_knee_flexion"] == "no right hip among the landmarks"
    with open(run / "movement.csv", newline="") as file:
        rows = list(csv.reader(file))
    assert rows[0] == ["subject", "measure", "value", "unit"]
    knee_range = [row for row in rows if row[:2] == ["left_knee_flexion", "range_deg"]]
    assert len(knee_range) == 1 and float(knee_range[0][2]) == pytest.approx(knee["range_deg"]) and knee_range[0][3] == "deg"
    assert ["far", "mean_speed_m_s", "", "m/s"] in rows  # unknown: an empty cell


def test_exports_read_back(scene, tmp_path):
    run, path, truth = scene
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}"]) == 0
    files = {suffix: tmp_path / f"joints.{suffix}" for suffix in ("trc", "csv", "c3d")}
    assert main(["export", str(run), *(f"--{suffix}={file}" for suffix, file in files.items())]) == 0
    trc = read_trc(files["trc"])
    assert trc.names == NAMES and trc.rate == SessionReader(FittedRun.load(run).info.session).fps
    np.testing.assert_allclose(trc.positions[:, :CARRIED], truth[:, :CARRIED], atol=2e-6)
    names, positions, _ = read_c3d(files["c3d"])
    np.testing.assert_allclose(positions[:, :CARRIED], truth[:, :CARRIED], atol=1e-5)  # float32 millimetres
    assert np.isnan(positions[:, CARRIED]).all()
    assert read_landmark_csv(files["csv"])[0] == NAMES


def test_a_session_of_later_frames_numbers_its_landmarks_by_the_capture(tmp_path, capsys):
    """A session ingested with ``--frames 10::2``: landmarks.csv and its exports number rows by the capture's
    frames (as their times are), so the CSV reads back as itself through the ``csv`` source and the overlay
    video finds its frames; a file of frames the session never took is refused naming the frame."""
    import imageio.v3 as iio

    run, path, truth = tracked_scene(tmp_path, provenance={"frames": [10, None, 2]})
    with pytest.warns(UserWarning, match="landmarks far"):
        assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}"]) == 0
    names, frames, _, carried, _ = read_landmark_csv(run / "landmarks.csv")
    assert frames.tolist() == [10, 12, 14, 16, 18]
    record = json.loads((run / "landmarks.json").read_text())
    assert record["frames"] == [0, FRAMES] and record["capture_frames"] == [10, 19, 2]  # the run's own records: session frames
    np.testing.assert_allclose(carried[:, :CARRIED], truth[:, :CARRIED], atol=2e-6)
    session = SessionReader(FittedRun.load(run).info.session)
    again = CsvLandmarks(path=str(run / "landmarks.csv")).read(session, range(FRAMES))
    np.testing.assert_array_equal(again.positions, carried)
    assert main(["export", str(run), f"--csv={tmp_path / 'out.csv'}", f"--trc={tmp_path / 'out.trc'}"]) == 0
    assert read_landmark_csv(tmp_path / "out.csv")[1].tolist() == frames.tolist()
    exported = read_trc(tmp_path / "out.trc")
    assert exported.first_frame == 10 and exported.rate == session.fps == session.capture_fps / 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # half the capture's rate: every other frame, not a rate to warn of
        np.testing.assert_allclose(TrcLandmarks(path=str(tmp_path / "out.trc")).read(session, range(FRAMES)).positions, carried, atol=1e-5)
    assert main(["render", str(run), "--landmarks", "--no-progress"]) == 0
    assert iio.imread(run / "renders" / "landmarks_cam_0.mp4").shape[0] == FRAMES
    assert main(["report", str(run)]) == 0
    assert "session frame k is the capture&#x27;s frame 10 + 2·k" in (run / "report.html").read_text()
    text = (run / "landmarks.csv").read_text().replace("\n10,", "\n11,")  # a frame this session never took
    (run / "landmarks.csv").write_text(text)
    capsys.readouterr()
    assert main(["export", str(run), f"--csv={tmp_path / 'out.csv'}"]) == 2
    assert "landmarks.csv: capture frame 11 is not one of session" in capsys.readouterr().err


def test_a_trc_export_takes_the_axes_of_its_sessions_world(scene, tmp_path, monkeypatch):
    """A session calibrated by OpenCap (its world the board's: storage.opencap_session.trc_convention) exports
    in OpenCap's Y-up axes, not in Pose2Sim's, which take the world's z for up."""
    run, path, truth = scene
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}"]) == 0
    monkeypatch.setattr(landmark_export, "trc_convention", lambda session: "opencap-ground")
    assert main(["export", str(run), f"--trc={tmp_path / 'joints.trc'}"]) == 0
    np.testing.assert_allclose(read_trc(tmp_path / "joints.trc", "opencap-ground").positions[:, :CARRIED], truth[:, :CARRIED], atol=2e-6)
    assert not np.allclose(read_trc(tmp_path / "joints.trc", "pose2sim").positions[:, :CARRIED], truth[:, :CARRIED], atol=1e-3)


def test_a_trc_at_another_rate_than_the_video_is_said(scene, tmp_path):
    """A marker system's TRC (100 Hz) beside 30 fps video: row k is not frame k, and the reader says so."""
    run, _, truth = scene
    session = SessionReader(FittedRun.load(run).info.session)
    for rate, said in ((session.capture_fps, False), (session.capture_fps * 1.005, False), (100.0, True)):
        write_trc(tmp_path / "m.trc", NAMES, np.arange(len(truth)) / rate, truth, rate)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            TrcLandmarks(path=str(tmp_path / "m.trc")).read(session, [0])
        assert any("DataRate 100 Hz, but the capture of session" in str(w.message) for w in caught) == said


def test_a_trc_of_later_frames_is_read_at_them_and_what_it_lacks_is_said(scene, tmp_path):
    """Pose2Sim trims a trial to where the subject is seen and writes its first frame as OrigDataStartFrame: its
    rows are those frames, not the capture's from 0; frames a TRC does not cover are NaN, and said."""
    run, _, truth = scene
    session = SessionReader(FittedRun.load(run).info.session)
    frames = list(range(len(truth)))
    write_trc(tmp_path / "m.trc", NAMES, np.arange(len(truth) - 1) / session.capture_fps, truth[1:], session.capture_fps)
    text = (tmp_path / "m.trc").read_text().splitlines()
    values = text[2].split("\t")
    values[6] = "1"  # OrigDataStartFrame 1 with its first row one frame in: Pose2Sim's frame 1
    rows = [f"{k + 1}\t{(k + 1) / session.capture_fps}\t" + row.split("\t", 2)[2] for k, row in enumerate(text[5:])]
    (tmp_path / "m.trc").write_text("\n".join([*text[:2], "\t".join(values), *text[3:5], *rows]) + "\n")
    with pytest.warns(UserWarning, match=r"rows are the capture's frames 1–\d+ \(its OrigDataStartFrame\); 1 of the \d+ frames asked for \(0…0\)"):
        read = TrcLandmarks(path=str(tmp_path / "m.trc")).read(session, frames)
    assert np.isnan(read.positions[0]).all()
    np.testing.assert_allclose(read.positions[1:], truth[1:], atol=1e-6, equal_nan=True)


def test_a_csv_that_lacks_frames_asked_for_says_so(scene, tmp_path):
    run, _, truth = scene
    session = SessionReader(FittedRun.load(run).info.session)
    write_landmark_csv(tmp_path / "later.csv", NAMES, np.arange(1, len(truth)), np.arange(1, len(truth)) / 30, truth[1:])
    with pytest.warns(UserWarning, match=r"CSV .*later.csv: its rows are the capture's frames 1–\d+; 1 of the \d+ frames asked for \(0…0\)"):
        read = CsvLandmarks(path=str(tmp_path / "later.csv")).read(session, range(len(truth)))
    assert np.isnan(read.positions[0]).all() and np.isfinite(read.positions[1:]).any()


def test_no_landmark_near_the_subject_is_an_error(scene, tmp_path, capsys):
    run, _, _ = scene
    far = tmp_path / "far.csv"
    far.write_text("name,x,y,z\nhead,5,5,5\n")
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={far}"]) == 2
    assert "no landmark of CSV" in capsys.readouterr().err
    mm = tmp_path / "mm.csv"
    mm.write_text("name,x,y,z\nwrist,100,30,0\n")  # millimetres read as metres, then told
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={mm}"]) == 2
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={mm}", "--set", "units=mm"]) == 0


def test_bind_frames_chooses_the_frames_bound_from_and_left_unscored(scene, capsys):
    run, path, _ = scene
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}", "--bind-frames", "0"]) == 2
    assert "--bind-frames must be ≥ 1" in capsys.readouterr().err
    with pytest.warns(UserWarning, match="landmarks far"):
        assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}", "--bind-frames", "1"]) == 0
    info = json.loads((run / "landmarks.json").read_text())
    assert info["bind_frames"] == 1 and info["accuracy_3d"]["pairs"] == CARRIED * (FRAMES - 1)


def test_the_overlay_video_and_the_report_show_them(scene):
    import imageio.v3 as iio

    run, path, _ = scene
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}"]) == 0
    assert main(["render", str(run), "--landmarks", "--no-progress"]) == 0
    video = run / "renders" / "landmarks_cam_0.mp4"
    frames = iio.imread(video)
    assert frames.shape[0] == FRAMES and min(frames.shape[1:3]) >= 480
    assert main(["report", str(run)]) == 0
    page = (run / "report.html").read_text()
    assert "<h2>Movement</h2>" in page and "Where the hands and feet went" in page and "Left and right" in page
    assert "3D error where the landmark moved" in page and "landmarks_cam_0.mp4" in page
    assert "<h3>Joint angles</h3>" in page and "joint angles over time" in page and "0° with the leg straight" in page
    assert "right knee flexion (no right hip among the landmarks)" in page and "joint angle error, median (°)" in page


def test_a_stop_while_the_landmarks_are_written_leaves_all_four_new(scene, tmp_path, monkeypatch):
    """Ctrl-C between landmarks.csv and the record beside it waits until the four files are written: never a
    new landmarks.csv beside the old landmarks.json and movement measures."""
    import os
    import signal

    import mmcsplat.pipeline.landmarks as landmarks_step

    run, path, _ = scene
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}"]) == 0
    names = ("landmarks.csv", "landmarks.json", "movement.json", "movement.csv")
    for name in names:
        (run / name).write_text("old")
    written = landmarks_step.write_landmark_csv

    def then_stop(*args, **kwargs):
        written(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(landmarks_step, "write_landmark_csv", then_stop)
    with pytest.raises(KeyboardInterrupt):
        landmarks_step.track_landmarks(run, "csv", {"path": str(path)})
    assert all((run / name).read_text() != "old" for name in names)


def test_a_run_without_an_opaque_subject_gaussian_says_so(scene, capsys, monkeypatch):
    """A fit that failed leaves no Gaussian opaque enough to carry a landmark: said as such, not as landmarks
    "not within 10 cm (none is known there)", which sent the user to the file's units."""
    import mmcsplat.scene.landmark_anchors as anchors

    run, path, _ = scene
    monkeypatch.setattr(anchors, "SUBJECT_OPACITY", 1.1)  # every Gaussian too faint
    assert main(["landmarks", str(run), "--source", "csv", "--set", f"path={path}"]) == 2
    assert "no subject Gaussian can carry a landmark: none at frame 0 is at least 0.1 opaque" in capsys.readouterr().err
