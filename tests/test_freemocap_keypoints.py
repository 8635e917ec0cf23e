"""FreeMoCap's 2D keypoints (one .npy of every camera, MediaPipe's or YOLO's points): read in the recording's
camera order with MediaPipe's pixel centres, named as OpenPose names the joints, triangulated to the joints
they were projected from, and found by ``mmcsplat run`` in a recording folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import zarr
from fitting_scene import write_session
from test_keypoints import FIGURE, FRAMES, UNDETECTED, figure_at, figure_named

from mmcsplat.configuration.registry import default_registry
from mmcsplat.pipeline.capture_session import keypoint_folder, keypoint_source
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugins.dynamics.body_parts import HUMAN_PARTS, part_members
from mmcsplat.plugins.landmarks.freemocap import MEDIAPIPE_POINTS
from mmcsplat.plugins.landmarks.keypoint_models import COCO, MEDIAPIPE_BODY
from mmcsplat.plugins.landmarks.openpose import MODELS
from mmcsplat.plugins.segmenters.keypoints import midpoint_keypoints
from mmcsplat.scene.human_skeleton import openpose_name, with_midpoints
from mmcsplat.storage.session import SessionReader

RAW = Path("output_data") / "raw_data"
FILE = "mediapipe_2dData_numCams_numFrames_numTrackedPoints_pixelXY.npy"


def _slot(names: tuple[str, ...], joint: str) -> int | None:
    converted = [openpose_name(name) for name in names]
    return converted.index(joint) if joint in converted else None


def write_recording(root: Path, reader: SessionReader, order: list[str], names: tuple[str, ...] = MEDIAPIPE_BODY,
                    points: int = MEDIAPIPE_POINTS) -> Path:
    """A FreeMoCap recording of the figure: ``synchronized_videos/`` (empty stand-ins named after the cameras) and the
    2D file, its cameras in ``order``, MediaPipe's pixel centres (+0.5), a relative depth in the third value, and the
    head undetected (NaN) at frame 1."""
    (root / "synchronized_videos").mkdir(parents=True)
    for name in reader.camera_names:
        (root / "synchronized_videos" / f"{name}.mp4").write_bytes(b"")
    data = np.full((len(order), FRAMES, points, 3), np.nan)
    for row, name in enumerate(order):
        camera = reader.camera(name)
        for t in range(FRAMES):
            for joint in FIGURE:
                slot = _slot(names, joint)
                if slot is not None and (joint, t) != UNDETECTED:
                    data[row, t, slot, :2] = camera.project(figure_at(t)[[MODELS["BODY_25B"].index(joint)]])[0] + 0.5
                    data[row, t, slot, 2] = -40.0
    (root / RAW).mkdir(parents=True)
    np.save(root / RAW / FILE, data)
    return root / RAW / FILE


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return write_session(tmp_path_factory.mktemp("freemocap") / "session.zarr", frames=FRAMES, zoom=4)


def test_mediapipe_keypoints_triangulate_to_the_joints_they_came_from(session, tmp_path):
    reader = SessionReader(session)
    path = write_recording(tmp_path / "recording", reader, sorted(reader.camera_names, key=str.lower))
    landmarks = default_registry().create("landmarks", "freemocap", path=str(path)).read(reader, range(FRAMES))
    assert len(landmarks.names) == 33 and landmarks.names[:3] == ("Nose", "left_eye_inner", "LEye")
    assert {"LShoulder", "RHip", "LKnee", "RAnkle", "LHeel", "RBigToe", "left_pinky"} <= set(landmarks.names)
    np.testing.assert_allclose(landmarks.positions, figure_named(MEDIAPIPE_BODY), atol=1e-6)


def test_yolos_coco_keypoints_are_read_too(session, tmp_path):
    reader = SessionReader(session)
    path = write_recording(tmp_path / "recording", reader, sorted(reader.camera_names, key=str.lower), COCO, len(COCO))
    landmarks = default_registry().create("landmarks", "freemocap", path=str(path)).read(reader, range(FRAMES))
    assert landmarks.names[:6] == ("Nose", "LEye", "REye", "LEar", "REar", "LShoulder")
    np.testing.assert_allclose(landmarks.positions, figure_named(COCO), atol=1e-6)


def test_a_recording_in_another_camera_order_is_read_with_camera_order(session, tmp_path):
    """FreeMoCap before 1.6 took the videos in the folder's listing order: camera_order states it."""
    reader = SessionReader(session)
    order = list(reversed(reader.camera_names))
    path = write_recording(tmp_path / "recording", reader, order)
    source = default_registry().create("landmarks", "freemocap", path=str(path))
    assert np.nanmax(np.abs(source.read(reader, range(FRAMES)).positions - figure_named(MEDIAPIPE_BODY))) > 0.05  # in name order: wrong
    landmarks = default_registry().create("landmarks", "freemocap", path=str(path), camera_order=order).read(reader, range(FRAMES))
    np.testing.assert_allclose(landmarks.positions, figure_named(MEDIAPIPE_BODY), atol=1e-6)
    with pytest.raises(InputError, match=r"camera_order \['cam_0'\] must name the file's 5 cameras once each"):
        default_registry().create("landmarks", "freemocap", path=str(path), camera_order=["cam_0"]).read(reader, range(FRAMES))


def test_what_cannot_be_read_is_named(session, tmp_path):
    reader = SessionReader(session)
    path = write_recording(tmp_path / "recording", reader, sorted(reader.camera_names), MEDIAPIPE_BODY, 40)
    with pytest.raises(InputError, match=rf"{FILE}: 40 points, neither MediaPipe Holistic's 553 nor YOLO's 17"):
        default_registry().create("landmarks", "freemocap", path=str(path)).read(reader, range(FRAMES))
    np.save(path, np.zeros((len(reader.camera_names) + 1, FRAMES, 17, 3)))
    with pytest.raises(InputError, match=rf"{FILE}: 6 cameras, but .*synchronized_videos holds 5 .mp4 videos"):
        default_registry().create("landmarks", "freemocap", path=str(path)).read(reader, range(FRAMES))
    np.save(path, np.zeros((FRAMES, 17, 3)))
    with pytest.raises(InputError, match=r"shape \[3, 17, 3\], expected \[cameras, frames, points, 3\]"):
        default_registry().create("landmarks", "freemocap", path=str(path)).read(reader, range(FRAMES))


def test_run_finds_a_freemocap_recordings_keypoints(session, tmp_path):
    path = write_recording(tmp_path, SessionReader(session), list(SessionReader(session).camera_names))
    assert keypoint_folder(tmp_path, None) == path
    assert keypoint_source(path) == {"name": "freemocap", "path": str(path)}
    (tmp_path / "pose_2d").mkdir()  # a Pose2Sim folder beside it comes first, as before
    assert keypoint_folder(tmp_path, None) == tmp_path / "pose_2d"


def test_each_camera_is_the_video_it_was_ingested_from(tmp_path):
    """FreeMoCap names videos after the recording (``…_Camera_000.mp4``), the calibration its cameras otherwise: the
    session's record of which video each camera came from pairs them, not their names."""
    session = write_session(tmp_path / "session.zarr", frames=FRAMES, zoom=4)
    reader = SessionReader(session)
    videos = {name: f"rec_Camera_{k:03d}.mp4" for k, name in enumerate(reversed(reader.camera_names))}
    group = zarr.open_group(str(session), mode="r+")
    group.attrs["provenance"] = {**group.attrs["provenance"], "reader": {"videos": {name: f"/elsewhere/{video}" for name, video in videos.items()}}}
    path = write_recording(tmp_path / "recording", reader, sorted(videos, key=lambda name: videos[name]))
    for stem in reader.camera_names:  # the stand-ins named after the cameras give way to the recording's own names
        (tmp_path / "recording" / "synchronized_videos" / f"{stem}.mp4").rename(tmp_path / "recording" / "synchronized_videos" / videos[stem])
    landmarks = default_registry().create("landmarks", "freemocap", path=str(path)).read(SessionReader(session), range(FRAMES))
    np.testing.assert_allclose(landmarks.positions, figure_named(MEDIAPIPE_BODY), atol=1e-6)


def test_keypoints_without_a_neck_get_one_for_the_masks_and_the_parts(session, tmp_path):
    """MediaPipe's and COCO's keypoints name no neck or head centre: the masks' neck and the neck part need them."""
    reader = SessionReader(session)
    path = write_recording(tmp_path / "recording", reader, sorted(reader.camera_names, key=str.lower))
    observed = default_registry().create("landmarks", "freemocap", path=str(path)).observations(reader, range(FRAMES))[0]
    names, pixels, seen = midpoint_keypoints(observed)
    assert names[-2:] == ("Neck", "Head")
    shoulders = [observed.names.index("LShoulder"), observed.names.index("RShoulder")]
    np.testing.assert_allclose(pixels[:, -2], observed.pixels[:, shoulders].mean(axis=1))
    assert seen[:, -2].all() and not seen[:, -1].any()  # the figure has no ears
    joints = {name: np.full(3, k, dtype=float) for k, name in enumerate(("LShoulder", "RShoulder", "LEar", "REar", "LHip", "RHip", "Nose"))}
    joints["Head"] = np.full(3, 9.0)  # a head the keypoints name stays theirs
    added = with_midpoints(joints)
    np.testing.assert_allclose(added["Neck"], np.full(3, 0.5))
    assert added["Head"][0] == 9.0 and list(with_midpoints({"LShoulder": np.zeros(3)})) == ["LShoulder"]
    _, parts = part_members(np.zeros((1, 3)), with_midpoints({name: joints[name] for name in joints if name != "Head"}), HUMAN_PARTS, 1.0, 0.0)
    assert ("Neck", "Head") in parts and ("LShoulder", "RShoulder", "RHip", "LHip", "Neck") in parts
