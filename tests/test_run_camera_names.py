"""``mmcsplat run`` on a capture whose files are not named after the calibration's cameras: one
``camera_map`` (``--reader-set``) maps the videos and the 2D keypoints named like them, ``--keypoints-set``
gives the keypoints their own, and each error says where the map is set."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mmcsplat.configuration.registry import default_registry
from mmcsplat.jobs.capture import CaptureSettings, run_capture
from mmcsplat.pipeline.capture_session import joints_file, keypoints_with, missing_torso
from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import Landmarks, LandmarkSource
from mmcsplat.storage.session import SessionReader

DEMO = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pose2sim_demo"
#: The demo's cameras under names that neither match theirs nor pair with them in name order.
RENAMED = {"cam_01": "west", "cam_02": "north", "cam_03": "east", "cam_04": "south"}
needs_demo = pytest.mark.skipif(not DEMO.is_dir(), reason="needs ../shared/data/pose2sim_demo")


def renamed_capture(root: Path) -> Path:
    """The demo's videos, keypoint folders and calibration, the videos and folders named by :data:`RENAMED`."""
    capture = root / "rig"
    (capture / "videos").mkdir(parents=True)
    (capture / "pose_2d").mkdir()
    (capture / "Calib_qualisys.toml").symlink_to(DEMO / "Calib_qualisys.toml")
    for camera, name in RENAMED.items():
        number = camera[-2:]
        (capture / "videos" / f"{name}.mp4").symlink_to(DEMO / "videos" / f"cam{number}.mp4")
        (capture / "pose_2d" / name).symlink_to(DEMO / "pose_2d" / f"cam{number}", target_is_directory=True)
    return capture


def test_the_readers_camera_map_and_trial_name_the_keypoints_unless_they_are_given_their_own():
    source = {"name": "openpose", "folder": "/rig/pose_2d"}
    assert keypoints_with(source, {}, {"camera_map": RENAMED, "size_mismatch": "crop"}) == {**source, "camera_map": RENAMED}
    assert keypoints_with(source, {"camera_map": "order"}, {"camera_map": RENAMED}) == {**source, "camera_map": "order"}
    assert keypoints_with(source, {"min_confidence": 0.5}, {}) == {**source, "min_confidence": 0.5}
    # anipose's pose-2d/vid01-camA.h5 are one trial's files, as videos-raw/vid01-camA.avi are; OpenPose's camera folders are not per trial
    tables = {"name": "deeplabcut", "folder": "/rig/pose-2d"}
    assert keypoints_with(tables, {}, {"trial": "vid01"}) == {**tables, "trial": "vid01"}
    assert keypoints_with(tables, {"trial": "vid02"}, {"trial": "vid01"}) == {**tables, "trial": "vid02"}
    assert keypoints_with(source, {}, {"trial": "vid01"}) == source


class Stop(Exception):
    """Ends the run at its fit."""


@needs_demo
def test_one_camera_map_makes_keypoint_masks_from_files_named_otherwise(tmp_path, monkeypatch):
    capture, out = renamed_capture(tmp_path), tmp_path / "out"
    monkeypatch.setattr("mmcsplat.pipeline.fit.FirstFrameFit", lambda *args, **kwargs: (_ for _ in ()).throw(Stop()))
    camera_map = "camera_map={" + ", ".join(f'{camera}="{name}"' for camera, name in RENAMED.items()) + "}"
    said: list[str] = []
    settings = CaptureSettings(frames=(0, 3, None), scale=0.125, reader_options=(camera_map,))
    with pytest.raises(Stop):
        run_capture(capture, out, settings, progress=False, log=said.append)
    assert json.loads((out / "masks.json").read_text())["masks"] == "keypoints"
    assert any("run: keypoints: openpose from" in line and "camera_map=" in line for line in said)
    # Each camera's keypoints are its own: the same detections as the demo's folders named after the cameras.
    session = SessionReader(out / "session.zarr")
    unmapped = default_registry().create("landmarks", "openpose", folder=str(capture / "pose_2d"))
    with pytest.raises(MissingFileError, match=r"no keypoint folder for calibrated camera 'cam_01' .*\(the keypoint source's camera_map: "
                                         r"mmcsplat run --keypoints-set"):
        unmapped.observations(session, [0])
    mapped = default_registry().create("landmarks", "openpose", folder=str(capture / "pose_2d"), camera_map=RENAMED)
    named = default_registry().create("landmarks", "openpose", folder=str(DEMO / "pose_2d"))
    for seen, expected in zip(mapped.observations(session, [0, 1, 2]), named.observations(session, [0, 1, 2]), strict=True):
        assert seen.camera == expected.camera
        np.testing.assert_array_equal(seen.pixels, expected.pixels)


@needs_demo
def test_files_named_otherwise_say_where_their_camera_map_is_set(tmp_path):
    capture = renamed_capture(tmp_path)
    with pytest.raises(MissingFileError, match=r"no video for calibrated camera 'cam_01' .*\(the reader's camera_map: mmcsplat ingest --set, "
                                         r"mmcsplat run --reader-set\)"):
        run_capture(capture, tmp_path / "out", CaptureSettings(frames=(0, 3, None), scale=0.125), progress=False, log=lambda line: None)
    settings = CaptureSettings(frames=(0, 3, None), scale=0.125, reader_options=("camera_map=order",), keypoint_options=("nosuch=1",))
    with pytest.raises(InputError, match="--keypoints-set: landmarks 'openpose': unknown parameter"):
        run_capture(capture, tmp_path / "out", settings, progress=False, log=lambda line: None)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("folders", "expected"), [
    (("pose_2d", "pose-2d"), "pose_2d"),  # the Pose2Sim demo's
    (("pose", "pose-sync", "pose-associated"), "pose-associated"),  # today's Pose2Sim: what its triangulation reads
    (("pose", "pose-sync"), "pose-sync"),
    (("pose",), "pose"),
    (("pose-2d", "pose-2d-filtered"), "pose-2d-filtered"),  # anipose's filtered poses, what it triangulates when it filters
    (("pose-2d",), "pose-2d"),
    ((), None),
])
def test_run_finds_the_keypoints_pose2sim_and_anipose_write_beside_the_videos(tmp_path, folders, expected):
    capture = tmp_path / "session"
    capture.mkdir()
    for name in folders:
        (capture / name).mkdir()
        (capture / name / "trial-cam1.csv").write_text("scorer\n")
    said: list[str] = []
    with pytest.raises(InputError):  # no videos or calibration: refused at the ingest, after the keypoints were found
        run_capture(capture, tmp_path / "out", CaptureSettings(), progress=False, log=said.append)
    found = [line for line in said if line.startswith("run: keypoints:")]
    assert found == ([f"run: keypoints: deeplabcut from {capture / expected}"] if expected else [])


def test_the_joints_are_the_captures_single_trc_else_the_one_pose2sim_wrote_in_pose_3d(tmp_path):
    (tmp_path / "pose-3d").mkdir()
    (tmp_path / "pose-3d" / "trial_0-100.trc").write_text("")
    assert joints_file(tmp_path, None) == tmp_path / "pose-3d" / "trial_0-100.trc"
    (tmp_path / "joints.trc").write_text("")
    assert joints_file(tmp_path, None) == tmp_path / "joints.trc"
    (tmp_path / "joints.trc").unlink()
    (tmp_path / "pose-3d" / "trial_0-100_filt_butterworth.trc").write_text("")
    with pytest.raises(InputError, match=r"several joints TRC file candidates \(trial_0-100.trc, trial_0-100_filt_butterworth.trc\)"):
        joints_file(tmp_path, None)


class _Joints(LandmarkSource):
    """Fixed joints at frame 0, for the torso check alone."""

    def __init__(self, names, known):
        self.names, self.known = names, known

    def read(self, session, frames):
        positions = np.where(np.array(self.known)[:, None], np.arange(3.0), np.nan)
        return Landmarks(self.names, [0], positions[None], source="the joints")


def test_body_parts_are_held_only_where_the_joints_name_a_torso_at_the_fitted_frame():
    human = ("LShoulder", "RShoulder", "RHip", "LHip", "Nose")
    assert missing_torso(_Joints(human, [True] * 5), None, 0) is None
    synthetic = ("shoulder_left", "shoulder_right", "hip_right", "hip_left")  # mmcsplat synth's joints
    assert missing_torso(_Joints(synthetic, [True] * 4), None, 0) is None
    # A detection missed in all but one camera at the fitted frame, and an animal's keypoints: said, not an error after the fit.
    assert missing_torso(_Joints(human, [True, True, False, True, True]), None, 0) == "the joints at frame 0: RHip not known there"
    mouse = ("snout", "ear_left", "ear_right", "tailbase")
    assert missing_torso(_Joints(mouse, [True] * 4), None, 0) == ("the joints at frame 0: no LShoulder, RShoulder, RHip, LHip among "
                                                                  "snout, ear_left, ear_right, tailbase")


def test_run_starts_where_a_trimmed_trcs_joints_start(tmp_path):
    """Today's Pose2Sim trims a trial to where the subject is seen: its TRC starts at OrigDataStartFrame. run
    starts there, so the fitted frame binds the joints; a --frames start before it is refused, naming it."""
    from mmcsplat.jobs.capture import frames_with_joints
    from mmcsplat.storage.landmark_formats import write_trc

    trc = tmp_path / "trial_3-10.trc"
    write_trc(trc, ["Neck"], (3 + np.arange(7)) / 30, np.zeros((7, 1, 3)), 30, first_frame=3)
    said = []
    assert frames_with_joints(CaptureSettings(), trc, said.append).frames == (3, None, None)
    assert said == [f"run: frames from 3 on, where the joints of {trc} start (its OrigDataStartFrame)"]
    assert frames_with_joints(CaptureSettings(frames=(5, 9, None)), trc, said.append).frames == (5, 9, None)
    with pytest.raises(InputError, match=r"--frames 0:9: the joints .* start at the capture's frame 3 .*: give --frames 3:9"):
        frames_with_joints(CaptureSettings(frames=(0, 9, None)), trc, said.append)
