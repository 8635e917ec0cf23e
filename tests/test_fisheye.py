"""Fisheye cameras (OpenCV's Kannala–Brandt model): the lens model, calibration files as aniposelib writes
them, ingest's undistortion into pinhole images, and keypoints mapped into those images."""

from __future__ import annotations

import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest
import rig_fixtures as rig
import tomli_w

from mmcsplat.pipeline.ingest import ingest
from mmcsplat.plugins.landmarks.triangulation import to_session_pixels
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import read_calibration, write_calibration

K = np.array([[880.0, 0.0, 955.0], [0.0, 880.0, 545.0], [0.0, 0.0, 1.0]])
#: A GoPro-like lens at 1920 × 1080: its corners see 51° off the axis.
LENS = [0.05, -0.02, 0.01, -0.002]
POINTS = np.random.default_rng(0).uniform([-2.0, -1.0, 1.0], [2.0, 1.0, 3.0], (50, 3))


def _camera(distortion=LENS, **changes) -> Camera:
    return Camera(**{"name": "gopro", "width": 1920, "height": 1080, "K": K, "R": np.eye(3), "t": np.zeros(3),
                     "distortion": distortion, "fisheye": True, **changes})


def test_projection_is_the_kannala_brandt_model_and_undistort_inverts_it() -> None:
    camera = _camera()
    normalized = POINTS[:, :2] / POINTS[:, 2:]
    radius = np.linalg.norm(normalized, axis=1)
    theta = np.arctan(radius)
    reached = theta * (1 + sum(k * theta ** (2 * i + 2) for i, k in enumerate(LENS)))
    expected = normalized * (reached / radius)[:, None] * 880.0 + [955.0, 545.0]
    np.testing.assert_allclose(camera.project(POINTS), expected, atol=1e-9)
    np.testing.assert_allclose(camera.distort(normalized), expected, atol=1e-9)
    np.testing.assert_allclose(camera.undistort(expected), normalized, atol=1e-9)
    pinhole = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(camera.undistort(expected, pinhole), normalized * 500.0 + [320.0, 240.0], atol=1e-6)
    # Without coefficients a fisheye is the equidistant projection, not a pinhole.
    assert _camera(distortion=[]).is_distorted
    assert Camera.from_dict(camera.to_dict()).fisheye and "fisheye" not in _camera(fisheye=False).to_dict()
    with pytest.raises(ValueError, match=r"camera 'gopro': a fisheye camera's distortion must be 0 or 4 values \(k1 k2 k3 k4\)"):
        _camera(distortion=[*LENS, 0.0])


def test_calibration_round_trip_as_aniposelib_writes_it(tmp_path: Path) -> None:
    cameras = rig.ring_cameras(["A", "B"], fisheye=True)
    path = tmp_path / "calibration.toml"
    write_calibration(path, cameras)
    table = tomllib.loads(path.read_text())["cam_0"]
    assert table["fisheye"] is True and table["distortions"] == list(rig.FISHEYE)  # aniposelib's FisheyeCamera.get_dict
    read = read_calibration(path)
    for camera, again in zip(cameras, read, strict=True):
        assert again.fisheye
        np.testing.assert_allclose(again.project(rig.MARKERS), camera.project(rig.MARKERS), atol=1e-9)


@pytest.mark.parametrize("change, message", [
    ({"distortions": [0.05, -0.02, 0.01, 0.0, 0.0]}, r"\[cam_0\]: a fisheye camera's distortions must hold 4 values"),
    ({"distortions": [-0.5, 0.0, 0.0, 0.0]}, r"calibration\.toml: camera 'a': its fisheye distortion \(k1 = -0.5, k2 = 0, k3 = 0, k4 = 0\) folds the "
                                             r"image over itself 47° from the optical axis"),
    ({"fisheye": "yes"}, r"\[cam_0\]: fisheye must be true or false, got 'yes'"),
])
def test_bad_fisheye_tables_are_refused(tmp_path: Path, change: dict, message: str) -> None:
    table = {"name": "a", "size": [640, 480], "matrix": [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]], "distortions": [0.0] * 4,
             "rotation": [0.0, 0.0, 0.0], "translation": [0.0, 0.0, 1.0], "fisheye": True, **change}
    path = tmp_path / "calibration.toml"
    path.write_text(tomli_w.dumps({"cam_0": table}))
    with pytest.raises(ValueError, match=message):
        read_calibration(path)


def test_ingest_undistorts_a_fisheye_rig_into_pinhole_images(tmp_path: Path) -> None:
    calibrated = rig.make_capture(tmp_path / "capture", names=("A", "B"), frames=2, fisheye=True)
    session = ingest(tmp_path / "capture", tmp_path / "out.zarr", progress=False)
    for camera in calibrated:
        stored = session.camera(camera.name)
        assert not stored.is_distorted and session.recorded_cameras()[camera.name].fisheye
        size = (camera.width, camera.height)
        new_K = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(camera.K, np.array(rig.FISHEYE), size, np.eye(3), balance=0.0)
        np.testing.assert_allclose(stored.K, new_K)
        rgb = session.frame(1, camera.name).rgb
        # Markers sit where the pinhole camera projects them (mp4v is lossy: 0.5 px), and they would be
        # pixels away had the frames been stored as recorded.
        assert rig.marker_offsets(rgb, stored).max() < 0.5
        assert rig.marker_offsets(rig.frame_image(camera, 1), stored).max() > 2.0
        # A keypoint detected in the recorded video lands on the same marker in the stored image.
        np.testing.assert_allclose(to_session_pixels(camera.project(rig.MARKERS), camera, stored), stored.project(rig.MARKERS), atol=1e-6)
