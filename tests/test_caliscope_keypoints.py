"""Caliscope's 2D keypoints (a body tracker's ``xy_TRACKER.csv`` of every camera): keypoint ids named by the
tracker's model card, cameras by their ``cam_id``, triangulated to the joints they were projected from; both
Caliscope's current columns and those before 0.7; found by ``mmcsplat run`` in a recording folder."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from fitting_scene import write_session
from test_keypoints import FIGURE, FRAMES, UNDETECTED, figure_at, figure_named

from mmcsplat.configuration.registry import default_registry
from mmcsplat.pipeline.capture_session import keypoint_folder, keypoint_source
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugins.landmarks.keypoint_models import HALPE26, MEDIAPIPE_BODY
from mmcsplat.plugins.landmarks.openpose import MODELS
from mmcsplat.scene.human_skeleton import openpose_name
from mmcsplat.storage.session import SessionReader

CURRENT = ("sync_index", "cam_id", "frame_index", "frame_time", "object_id", "keypoint_id", "img_loc_x", "img_loc_y", "obj_loc_x",
           "obj_loc_y", "obj_loc_z")
BEFORE_0_7 = ("sync_index", "port", "frame_index", "frame_time", "point_id", "img_loc_x", "img_loc_y", "obj_loc_x", "obj_loc_y")


def write_xy(path: Path, reader: SessionReader, names: tuple[str, ...], columns: tuple[str, ...] = CURRENT, offset: int = 0) -> Path:
    """The figure's keypoints as a Caliscope tracker writes them (ids ``offset`` + position in ``names``), the nose left
    out at frame 1 (under the tracker's threshold)."""
    converted = [openpose_name(name) for name in names]
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, columns)
        writer.writeheader()
        for t in range(FRAMES):
            for number, name in enumerate(reader.camera_names):
                camera = reader.camera(name)
                for joint in FIGURE:
                    if joint not in converted or (joint, t) == UNDETECTED:
                        continue
                    x, y = camera.project(figure_at(t)[[MODELS["BODY_25B"].index(joint)]])[0]
                    values = {"sync_index": t, "cam_id": number, "port": number, "frame_index": t, "frame_time": t / 30, "object_id": 0,
                              "keypoint_id": offset + converted.index(joint), "point_id": offset + converted.index(joint),
                              "img_loc_x": f"{x:.6f}", "img_loc_y": f"{y:.6f}"}
                    writer.writerow({key: values.get(key, "") for key in columns})
    return path


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return write_session(tmp_path_factory.mktemp("caliscope") / "session.zarr", frames=FRAMES, zoom=4)


def test_an_rtmpose_halpe26_tracker_triangulates_to_the_joints_it_came_from(session, tmp_path):
    reader = SessionReader(session)
    path = write_xy(tmp_path / "ONNX_rtmpose_m_halpe26" / "xy_ONNX_rtmpose_m_halpe26.csv", reader, HALPE26)
    landmarks = default_registry().create("landmarks", "caliscope", path=str(path)).read(reader, range(FRAMES))
    assert landmarks.names[:6] == ("Nose", "LEye", "REye", "LEar", "REar", "LShoulder")
    assert landmarks.names[17:] == ("Head", "Neck", "MidHip", "LBigToe", "RBigToe", "LSmallToe", "RSmallToe", "LHeel", "RHeel")
    np.testing.assert_allclose(landmarks.positions, figure_named(HALPE26), atol=1e-4)  # Caliscope writes 6 decimals


def test_a_mediapipe_holistic_file_before_caliscope_0_7_reads_its_body(session, tmp_path):
    """Ports, point ids, and the holistic tracker's hands from id 100 on, which are not read."""
    reader = SessionReader(session)
    path = write_xy(tmp_path / "HOLISTIC" / "xy_HOLISTIC.csv", reader, MEDIAPIPE_BODY, BEFORE_0_7)
    with path.open("a") as file:
        file.write("0,0,0,0.0,100,10.0,10.0,,\n")  # the right hand's wrist
    landmarks = default_registry().create("landmarks", "caliscope", path=str(path)).read(reader, range(FRAMES))
    assert len(landmarks.names) == 33
    np.testing.assert_allclose(landmarks.positions, figure_named(MEDIAPIPE_BODY), atol=1e-4)


def test_a_tracker_of_ones_own_is_named_by_its_model_card(session, tmp_path):
    reader = SessionReader(session)
    names = ("left_knee", "right_knee", "left_hip", "right_hip")
    path = write_xy(tmp_path / "ONNX_my_legs" / "xy_ONNX_my_legs.csv", reader, names)
    with pytest.raises(InputError, match=r"Caliscope tracker 'ONNX_my_legs': its keypoints' names are not known here .*model_card=FILE.toml"):
        default_registry().create("landmarks", "caliscope", path=str(path)).read(reader, range(FRAMES))
    card = tmp_path / "my_legs.toml"
    card.write_text('[model]\nname = "legs"\n\n[points]\n' + "".join(f"{name} = {k}\n" for k, name in enumerate(names)))
    landmarks = default_registry().create("landmarks", "caliscope", path=str(path), model_card=str(card)).read(reader, range(FRAMES))
    assert landmarks.names == ("LKnee", "RKnee", "LHip", "RHip")
    np.testing.assert_allclose(landmarks.positions, figure_named(names), atol=1e-4)


def test_what_cannot_be_read_is_named(session, tmp_path):
    reader = SessionReader(session)
    path = tmp_path / "ONNX_rtmpose_m_halpe26" / "xy_ONNX_rtmpose_m_halpe26.csv"
    write_xy(path, reader, HALPE26, tuple(column for column in CURRENT if column != "frame_index"))
    with pytest.raises(InputError, match=r"no frame_index column .*: not a Caliscope tracker's 2D output of a recording"):
        default_registry().create("landmarks", "caliscope", path=str(path)).read(reader, range(FRAMES))
    path.write_text(",".join(CURRENT) + "\n0,0,0,0.0,0,5,x,1.0,2.0,,,\n")
    with pytest.raises(InputError, match=r"xy_ONNX_rtmpose_m_halpe26.csv, line 2: not numbers"):
        default_registry().create("landmarks", "caliscope", path=str(path)).read(reader, range(FRAMES))
    path.write_text(",".join(CURRENT) + "\n0,7,0,0.0,0,5,1.0,2.0,,,\n")
    with pytest.raises(InputError, match=r"no detections of cam_id 0, 1, 2, 3, 4 \(it holds cam_id 7\)"):
        default_registry().create("landmarks", "caliscope", path=str(path)).read(reader, range(FRAMES))


def test_run_finds_a_caliscope_recordings_body_tracker(session, tmp_path):
    reader = SessionReader(session)
    write_xy(tmp_path / "CHARUCO" / "xy_CHARUCO.csv", reader, HALPE26)  # a board's points: not a body
    assert keypoint_folder(tmp_path, None) is None
    path = write_xy(tmp_path / "ONNX_rtmpose_m_halpe26" / "xy_ONNX_rtmpose_m_halpe26.csv", reader, HALPE26)
    assert keypoint_folder(tmp_path, None) == path
    assert keypoint_source(path) == {"name": "caliscope", "path": str(path)}
    write_xy(tmp_path / "POSE" / "xy_POSE.csv", reader, MEDIAPIPE_BODY)
    with pytest.raises(InputError, match=r"several Caliscope trackers' keypoints \(ONNX_rtmpose_m_halpe26, POSE\); choose one"):
        keypoint_folder(tmp_path, None)
