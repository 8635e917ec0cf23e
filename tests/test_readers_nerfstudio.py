"""The nerfstudio reader (transforms.json) on small fixtures made here from known cameras."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from mmcsplat.configuration.registry import default_registry
from mmcsplat.datasets.nerfstudio import NerfstudioReader
from mmcsplat.pipeline.ingest import detect_format
from mmcsplat.scene.camera import Camera, look_at
from mmcsplat.storage.session import SessionReader

W, H = 16, 12
#: Known cameras (mmcsplat's conventions: OpenCV axes, pixel centres at integers), one distorted.
CENTRES = [(4.0, 0.0, 1.0), (0.0, 4.0, 1.5), (-3.0, -3.0, 0.5)]
INTRINSICS = [(20.0, 21.0, 7.2, 5.4), (18.0, 18.0, 7.5, 5.5), (22.0, 23.0, 8.1, 6.0)]
DISTORTIONS = [[], [0.05, -0.01, 0.001, -0.002], [0.02, 0.01, 0.0, 0.0, -0.003]]
POINT = np.array([[0.1, -0.2, 0.3]])


def known_cameras() -> list[Camera]:
    """The cameras the fixture is written from."""
    cameras = []
    for index, (centre, (fx, fy, cx, cy), distortion) in enumerate(zip(CENTRES, INTRINSICS, DISTORTIONS)):
        R = look_at(centre, (0.0, 0.0, 0.0))
        cameras.append(Camera(name=f"view{index}", width=W, height=H, K=[[fx, 0, cx], [0, fy, cy], [0, 0, 1]], R=R,
                              t=-R @ np.array(centre), distortion=distortion))
    return cameras


def _c2w_gl(camera: Camera) -> np.ndarray:
    """nerfstudio's transform_matrix: camera-to-world with OpenGL axes (OpenCV's y and z negated)."""
    c2w = np.eye(4)
    c2w[:3, :3] = camera.R.T @ np.diag([1.0, -1.0, -1.0])
    c2w[:3, 3] = camera.center
    return c2w


def _intrinsics(camera: Camera) -> dict:
    """nerfstudio's keys: the principal point in coordinates whose pixel centres are at +0.5."""
    entry = {"fl_x": camera.K[0, 0], "fl_y": camera.K[1, 1], "cx": camera.K[0, 2] + 0.5, "cy": camera.K[1, 2] + 0.5, "w": W, "h": H}
    names = ("k1", "k2", "p1", "p2", "k3")
    entry.update({name: float(value) for name, value in zip(names, camera.distortion)})
    return entry


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)


def make_nerfstudio(root: Path, images_per_camera: int = 1, extra: dict | None = None) -> Path:
    """A nerfstudio folder: camera 0's intrinsics at the top level, the others per frame, PNG images."""
    cameras = known_cameras()
    frames = []
    for number in range(images_per_camera):
        for index, camera in enumerate(cameras):
            stem = camera.name if images_per_camera == 1 else f"{camera.name}_{number:02d}"
            image = root / "images" / f"{stem}.png"
            image.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(image), cv2.cvtColor(_image(10 * index + number), cv2.COLOR_RGB2BGR))
            entry = {"file_path": f"images/{stem}.png", "transform_matrix": _c2w_gl(camera).tolist()}
            if index:
                entry.update(_intrinsics(camera))
            frames.append(entry)
    document = {"camera_model": "OPENCV", **_intrinsics(cameras[0]), "frames": frames, **(extra or {})}
    (root / "transforms.json").write_text(json.dumps(document))
    return root


def _edit(root: Path, edit) -> None:
    path = root / "transforms.json"
    document = json.loads(path.read_text())
    edit(document)
    path.write_text(json.dumps(document))


def _expected_pixel(camera: Camera, point: np.ndarray) -> np.ndarray:
    """``point`` projected as nerfstudio does, through the written file's values, then shifted to pixel indices."""
    entry, c2w = _intrinsics(camera), _c2w_gl(camera)
    gl = np.linalg.inv(c2w) @ np.append(point, 1.0)
    x, y = gl[0] / -gl[2], -gl[1] / -gl[2]  # OpenGL looks along −z with y up: image y points down
    k1, k2, p1, p2, k3 = (entry.get(name, 0.0) for name in ("k1", "k2", "p1", "p2", "k3"))
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.array([entry["fl_x"] * xd + entry["cx"] - 0.5, entry["fl_y"] * yd + entry["cy"] - 0.5])


def test_registered_and_detects_only_its_layout(tmp_path):
    reader = default_registry().create("reader", "nerfstudio")
    assert isinstance(reader, NerfstudioReader)
    root = make_nerfstudio(tmp_path / "ns")
    assert reader.detect(root) and detect_format(root) == "nerfstudio"
    (tmp_path / "dnerf").mkdir()
    (tmp_path / "dnerf" / "transforms_train.json").write_text("{}")
    assert not reader.detect(tmp_path / "dnerf")
    (tmp_path / "dnerf" / "transforms.json").write_text("{}")  # a D-NeRF folder that also has a transforms.json stays dnerf's
    assert not reader.detect(tmp_path / "dnerf")
    assert not reader.detect(tmp_path / "empty")


def test_cameras_match_the_known_ones_and_project_alike(tmp_path):
    recording = NerfstudioReader().open(make_nerfstudio(tmp_path))
    assert [camera.name for camera in recording.cameras] == ["view0", "view1", "view2"]
    assert recording.num_frames == 1 and not recording.has_masks and recording.heldout == ()
    for expected, camera in zip(known_cameras(), recording.cameras):
        np.testing.assert_allclose(camera.K, expected.K, atol=1e-6)
        np.testing.assert_allclose(camera.R, expected.R, atol=1e-6)
        np.testing.assert_allclose(camera.t, expected.t, atol=1e-6)
        np.testing.assert_allclose(camera.distortion, expected.distortion, atol=1e-12)
        np.testing.assert_allclose(camera.project(POINT)[0], _expected_pixel(expected, POINT[0]), atol=1e-6)
        (frame,) = recording.frames(camera.name, range(1))
        assert frame.t == 0 and frame.mask is None
    np.testing.assert_array_equal(next(recording.frames("view2", range(1))).rgb, _image(20))


def test_agrees_with_mmcsplats_own_transforms_export(tmp_path):
    from mmcsplat.outputs.transforms_json import camera_to_world_gl, intrinsics

    root = make_nerfstudio(tmp_path)
    cameras = known_cameras()
    frames = [{"file_path": f"images/{camera.name}.png", **intrinsics(camera), "transform_matrix": camera_to_world_gl(camera).tolist()}
              for camera in cameras]
    (root / "transforms.json").write_text(json.dumps({"camera_model": "OPENCV", "frames": frames}))
    for expected, camera in zip(cameras, NerfstudioReader().open(root).cameras):
        np.testing.assert_allclose(camera.world_to_camera, expected.world_to_camera, atol=1e-9)
        np.testing.assert_allclose(camera.K, expected.K, atol=1e-12)


def test_ingest_through_the_cli(tmp_path):
    from mmcsplat.cli import main
    from mmcsplat.storage.session import SessionReader

    root = make_nerfstudio(tmp_path / "src")
    assert main(["ingest", str(root), str(tmp_path / "s.zarr"), "--no-progress"]) == 0
    session = SessionReader(tmp_path / "s.zarr")
    assert session.provenance["format"] == "nerfstudio" and session.num_frames == 1
    assert session.provenance["reader"]["principal_point"].startswith("cx, cy minus 0.5")
    for expected in known_cameras():
        stored = session.camera(expected.name)
        np.testing.assert_allclose(stored.world_to_camera, expected.world_to_camera, atol=1e-6)
        assert not stored.is_distorted
        if not expected.is_distorted:
            np.testing.assert_allclose(stored.K, expected.K, atol=1e-6)
            np.testing.assert_array_equal(session.frame(0, expected.name).rgb, _image(0))


def test_camera_and_time_keys_give_a_synchronised_rig(tmp_path):
    root = make_nerfstudio(tmp_path, images_per_camera=2)

    def add_keys(document):
        for index, frame in enumerate(document["frames"]):
            frame["camera"] = f"rig{index % 3}"
            frame["timestamp"] = [0.0, 0.04][index // 3]
        document["frames"].pop(4)  # rig1 lacks the second time

    _edit(root, add_keys)
    recording = NerfstudioReader().open(root)
    assert [camera.name for camera in recording.cameras] == ["rig0", "rig1", "rig2"]
    assert recording.num_frames == 2 and recording.fps == pytest.approx(25.0)
    np.testing.assert_allclose(recording.frame_times(), [0.0, 0.04])
    np.testing.assert_array_equal(recording.present("rig1"), [True, False])
    assert [frame.t for frame in recording.frames("rig2", range(2))] == [0, 1]
    _edit(root, lambda document: document["frames"][3]["transform_matrix"][0].__setitem__(3, 9.0))
    with pytest.raises(ValueError, match=r"transforms\.json: frames\[3\]: camera 'rig0' has a different pose .* than in frames\[0\]"):
        NerfstudioReader().open(root)


def test_without_times_the_kth_image_of_each_camera_is_frame_k(tmp_path):
    root = make_nerfstudio(tmp_path, images_per_camera=2)
    recording = NerfstudioReader(fps=10).open(root)
    assert [camera.name for camera in recording.cameras] == ["cam_000", "cam_001", "cam_002"]
    assert recording.num_frames == 2 and recording.fps == 10
    np.testing.assert_array_equal(next(recording.frames("cam_001", range(1, 2))).rgb, _image(11))
    _edit(root, lambda document: document["frames"].pop())
    with pytest.raises(ValueError, match=r"transforms\.json: cameras have different numbers of images .* no 'time'"):
        NerfstudioReader().open(root)


def test_masks_heldout_units_and_applied_transform(tmp_path):
    root = make_nerfstudio(tmp_path, extra={"val_filenames": ["images/view2.png"], "applied_transform": np.eye(4)[:3].tolist()})
    mask = np.zeros((H, W), np.uint8)
    mask[2:6, 3:9] = 255
    (root / "masks").mkdir()
    for name in ("view0", "view1", "view2"):
        cv2.imwrite(str(root / "masks" / f"{name}.png"), mask)
    _edit(root, lambda document: [frame.__setitem__("mask_path", f"masks/view{index}.png") for index, frame in enumerate(document["frames"])])
    recording = NerfstudioReader().open(root, units="mm")
    assert recording.has_masks and recording.heldout == ("view2",)
    np.testing.assert_array_equal(next(recording.frames("view0", range(1))).mask, mask > 0)
    np.testing.assert_allclose(recording.cameras[0].center, np.array(CENTRES[0]) * 1e-3)
    assert recording.describe()["applied_transform"] == np.eye(4)[:3].tolist()
    _edit(root, lambda document: document["frames"][1].pop("mask_path"))
    with pytest.raises(ValueError, match=r"transforms\.json: frames\[1\]: no 'mask_path'"):
        NerfstudioReader().open(root)


def test_unsupported_camera_model_names_file_and_frame(tmp_path):
    root = make_nerfstudio(tmp_path)
    _edit(root, lambda document: document["frames"][2].__setitem__("camera_model", "EQUIRECTANGULAR"))
    with pytest.raises(ValueError, match=r"transforms\.json: frames\[2\]: camera_model 'EQUIRECTANGULAR' is not supported"):
        NerfstudioReader().open(root)
    _edit(root, lambda document: (document["frames"][2].pop("camera_model"), document["frames"][2].__setitem__("k4", 0.1)))
    with pytest.raises(ValueError, match=r"transforms\.json: frames\[2\]: k4 = 0.1 is not supported"):
        NerfstudioReader().open(root)


def test_a_fisheye_frame_is_opencvs_fisheye_model(tmp_path):
    root = make_nerfstudio(tmp_path)
    lens = {"k1": 0.05, "k2": -0.02, "k3": 0.01, "k4": -0.002, "p1": 0.0, "p2": 0.0}
    _edit(root, lambda document: document["frames"][2].update(camera_model="OPENCV_FISHEYE", **lens))
    camera = NerfstudioReader().open(root).cameras[2]
    expected = known_cameras()[2]
    assert camera.fisheye and camera.distortion.tolist() == [0.05, -0.02, 0.01, -0.002]
    x, y, z = expected.R @ POINT[0] + expected.t
    radius = np.hypot(x / z, y / z)
    theta = np.arctan(radius)
    scale = theta * (1 + lens["k1"] * theta**2 + lens["k2"] * theta**4 + lens["k3"] * theta**6 + lens["k4"] * theta**8) / radius
    np.testing.assert_allclose(camera.project(POINT)[0], expected.K[:2, :2] @ [x / z * scale, y / z * scale] + expected.K[:2, 2], atol=1e-6)
    # mmcsplat's own export writes the same keys back
    from mmcsplat.outputs.transforms_json import intrinsics

    _edit(root, lambda document: document["frames"][2].update(intrinsics(camera)))
    assert NerfstudioReader().open(root).cameras[2].distortion.tolist() == camera.distortion.tolist()
    _edit(root, lambda document: document["frames"][2].update(p2=0.001))
    with pytest.raises(ValueError, match=r"transforms\.json: frames\[2\]: p2 = 0.001 is not supported with OPENCV_FISHEYE"):
        NerfstudioReader().open(root)


def test_missing_image_malformed_file_and_missing_intrinsics_name_the_file(tmp_path):
    root = make_nerfstudio(tmp_path)
    (root / "images" / "view1.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"transforms\.json: 1 of 3 not found: .*images/view1\.png"):
        NerfstudioReader().open(root)
    (root / "transforms.json").write_text('{"frames": [')
    with pytest.raises(ValueError, match=r"transforms\.json: not valid JSON"):
        NerfstudioReader().open(root)
    root = make_nerfstudio(tmp_path / "other")
    _edit(root, lambda document: document.pop("fl_x"))
    with pytest.raises(ValueError, match=r"transforms\.json: frames\[0\]: missing intrinsics 'fl_x'"):
        NerfstudioReader().open(root)
    root = make_nerfstudio(tmp_path / "third")
    _edit(root, lambda document: document["frames"][1]["transform_matrix"][0].__setitem__(0, 3.0))
    with pytest.raises(ValueError, match=r"transforms\.json: frames\[1\]: 'transform_matrix' is not a rigid"):
        NerfstudioReader().open(root)
    with pytest.raises(ValueError, match="--calibration is not supported"):
        NerfstudioReader().open(root, calibration=tmp_path / "calibration.toml")


def test_image_of_the_wrong_size_names_the_image(tmp_path):
    root = make_nerfstudio(tmp_path)
    cv2.imwrite(str(root / "images" / "view1.png"), np.zeros((H + 2, W, 3), np.uint8))
    with pytest.raises(ValueError, match=r"images/view1\.png is 16×14, but .*transforms\.json: frames\[1\] gives camera 'view1' 16×12"):
        list(NerfstudioReader().open(root).frames("view1", range(1)))


def test_missing_images_are_all_listed_or_skipped_on_request(tmp_path):
    root = make_nerfstudio(tmp_path, images_per_camera=3, extra={"val_filenames": ["images/view2_00.png", "images/view2_01.png",
                                                                                  "images/view2_02.png"]})
    for stem in ("view0_01", "view1_00", "view1_01", "view1_02"):
        (root / "images" / f"{stem}.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"4 of 9 not found: .*view1_00\.png, .*view0_01\.png, .*view1_01\.png, .*view1_02\.png .*--skip-missing"):
        NerfstudioReader().open(root)
    with pytest.warns(UserWarning, match=r"skipped 4 of 9 not found"):
        recording = NerfstudioReader(missing_frames="absent").open(root)
    # view1 lost every image and is left out; view0 lacks its middle frame, which keeps its index.
    assert [camera.name for camera in recording.cameras] == ["cam_000", "cam_002"]
    assert recording.heldout == ("cam_002",)
    assert recording.present("cam_000").tolist() == [True, False, True]
    assert [frame.t for frame in recording.frames("cam_000", range(3))] == [0, 2]
    assert len(recording.describe()["missing_images_skipped"]) == 4


def test_ingest_skip_missing_flag(tmp_path, capsys):
    from mmcsplat.cli import main

    root = make_nerfstudio(tmp_path / "capture")
    (root / "images" / "view1.png").unlink()
    assert main(["ingest", str(root), str(tmp_path / "s.zarr"), "--no-progress"]) == 2
    assert "1 of 3 not found" in capsys.readouterr().err and not (tmp_path / "s.zarr").exists()
    with pytest.warns(UserWarning, match="skipped 1 of 3 not found"):
        assert main(["ingest", str(root), str(tmp_path / "s.zarr"), "--no-progress", "--skip-missing"]) == 0
    assert [camera.name for camera in SessionReader(tmp_path / "s.zarr").cameras] == ["view0", "view2"]
