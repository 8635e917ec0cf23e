"""The d3dgs reader (Dynamic3DGaussians / CMU Panoptic layout) on small fixtures made here."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mmcsplat.configuration.registry import default_registry
from mmcsplat.datasets.d3dgs import D3DGSReader

W, H, T = 16, 12, 3
TRAIN_IDS, TEST_IDS = (0, 1, 3), (2,)


def _camera(cam_id: int) -> tuple[np.ndarray, np.ndarray]:
    """A distinct K and world-to-camera matrix for each camera id."""
    K = np.array([[20.0 + cam_id, 0.0, 7.5], [0.0, 21.0 + cam_id, 5.5], [0.0, 0.0, 1.0]])
    w2c = np.eye(4)
    w2c[:3, :3] = Rotation.from_rotvec([0.1 * cam_id, 0.3, -0.2]).as_matrix()
    w2c[:3, 3] = [0.1 * cam_id, -0.2, 3.0]
    return K, w2c


def _mask(t: int, cam_id: int) -> np.ndarray:
    mask = np.zeros((H, W), dtype=bool)
    mask[2 + t : 8, 3 + cam_id : 12] = True
    return mask


def make_d3dgs(root: Path, frames: int = T) -> Path:
    """A d3dgs folder: metas, flat-coloured JPEG images, and 1-bit PNG masks for the train cameras."""
    for meta, ids in (("train_meta.json", TRAIN_IDS), ("test_meta.json", TEST_IDS)):
        document = {"w": W, "h": H, "k": [], "w2c": [], "fn": [], "cam_id": []}
        for t in range(frames):
            cameras = [_camera(cam_id) for cam_id in ids]
            document["k"].append([K.tolist() for K, _ in cameras])
            document["w2c"].append([w2c.tolist() for _, w2c in cameras])
            document["fn"].append([f"{cam_id}/{t:06d}.jpg" for cam_id in ids])
            document["cam_id"].append(list(ids))
            for cam_id in ids:
                image = root / "ims" / str(cam_id) / f"{t:06d}.jpg"
                image.parent.mkdir(parents=True, exist_ok=True)
                # BGR on disk: blue rises with the camera, red with the frame.
                cv2.imwrite(str(image), np.full((H, W, 3), (40 * cam_id, 10, 60 * t + 40), np.uint8))
                if meta == "train_meta.json":
                    mask = root / "seg" / str(cam_id) / f"{t:06d}.png"
                    mask.parent.mkdir(parents=True, exist_ok=True)
                    cv2.imwrite(str(mask), _mask(t, cam_id).astype(np.uint8) * 255, [cv2.IMWRITE_PNG_BILEVEL, 1])
        (root / meta).write_text(json.dumps(document))
    return root


def _edit_meta(root: Path, meta: str, edit) -> None:
    path = root / meta
    document = json.loads(path.read_text())
    edit(document)
    path.write_text(json.dumps(document))


def test_registered_and_detects_only_its_layout(tmp_path):
    reader = default_registry().create("reader", "d3dgs")
    assert isinstance(reader, D3DGSReader)
    assert reader.detect(make_d3dgs(tmp_path / "d3dgs"))
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "transforms_train.json").write_text("{}")
    assert not reader.detect(tmp_path / "other")


def test_cameras_round_trip_and_heldout(tmp_path):
    recording = D3DGSReader().open(make_d3dgs(tmp_path))
    assert [camera.name for camera in recording.cameras] == ["cam_00", "cam_01", "cam_02", "cam_03"]
    assert recording.heldout == ("cam_02",)
    assert recording.num_frames == T and recording.fps == 30.0 and recording.has_masks
    for camera in recording.cameras:
        K, w2c = _camera(int(camera.name[4:]))
        np.testing.assert_allclose(camera.K, K)
        np.testing.assert_allclose(camera.world_to_camera, w2c, atol=1e-12)
        assert (camera.width, camera.height) == (W, H) and not camera.is_distorted
        assert recording.present(camera.name).all()


def test_frames_colour_order_masks_and_ranges(tmp_path):
    recording = D3DGSReader().open(make_d3dgs(tmp_path))
    frames = list(recording.frames("cam_03", range(1, 3)))
    assert [frame.t for frame in frames] == [1, 2]
    for frame in frames:
        assert frame.rgb.shape == (H, W, 3) and frame.rgb.dtype == np.uint8
        # JPEG keeps flat colours within a few levels; red (frame) comes first after the BGR swap.
        np.testing.assert_allclose(frame.rgb[H // 2, W // 2], (60 * frame.t + 40, 10, 120), atol=4)
        np.testing.assert_array_equal(frame.mask, _mask(frame.t, 3))
    test_frames = list(recording.frames("cam_02", range(T)))
    assert len(test_frames) == T and all(frame.mask is None for frame in test_frames)


def test_units_and_sparse_presence(tmp_path):
    root = make_d3dgs(tmp_path)

    def drop_camera_1_at_frame_2(document):
        for key in ("k", "w2c", "fn", "cam_id"):
            del document[key][2][1]

    _edit_meta(root, "train_meta.json", drop_camera_1_at_frame_2)
    recording = D3DGSReader().open(root, units="mm")
    np.testing.assert_array_equal(recording.present("cam_01"), [True, True, False])
    assert [frame.t for frame in recording.frames("cam_01", range(T))] == [0, 1]
    np.testing.assert_allclose(recording.cameras[1].t, _camera(1)[1][:3, 3] * 1e-3)


def test_calibration_replaces_cameras_by_name(tmp_path):
    from mmcsplat.scene.camera import Camera
    from mmcsplat.storage.calibration import write_calibration

    root = make_d3dgs(tmp_path / "src")
    names = ["cam_00", "cam_01", "cam_02", "cam_03"]
    cameras = [Camera(name, W, H, np.diag([30.0, 30.0, 1.0]), np.eye(3), [0.0, 0.0, i], [0.1, 0, 0, 0]) for i, name in enumerate(names)]
    write_calibration(tmp_path / "calibration.toml", cameras)
    recording = D3DGSReader().open(root, calibration=tmp_path / "calibration.toml")
    assert recording.cameras[3].K[0, 0] == 30.0 and recording.cameras[3].is_distorted
    write_calibration(tmp_path / "partial.toml", cameras[:2])
    with pytest.raises(ValueError, match="cam_02, cam_03"):
        D3DGSReader().open(root, calibration=tmp_path / "partial.toml")


def test_moving_camera_is_an_error(tmp_path):
    root = make_d3dgs(tmp_path)
    _edit_meta(root, "train_meta.json", lambda document: document["w2c"][2][1][0].__setitem__(3, 5.0))
    with pytest.raises(ValueError, match=r"train_meta\.json: frame 2.*cam_01.*frame 0"):
        D3DGSReader().open(root)


@pytest.mark.parametrize("key", ["w2c", "cam_id", "w"])
def test_missing_key_names_file_and_key(tmp_path, key):
    root = make_d3dgs(tmp_path)
    _edit_meta(root, "test_meta.json", lambda document: document.pop(key))
    with pytest.raises(ValueError, match=rf"test_meta\.json: missing key\(s\) '{key}'"):
        D3DGSReader().open(root)


def test_missing_image_and_mask_name_the_file(tmp_path):
    root = make_d3dgs(tmp_path)
    (root / "ims" / "2" / "000001.jpg").unlink()
    with pytest.raises(FileNotFoundError, match=r"test_meta\.json: 1 of 3 not found: .*ims/2/000001\.jpg"):
        D3DGSReader().open(root)
    root = make_d3dgs(tmp_path)
    (root / "seg" / "1" / "000002.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"mask of camera cam_01.*seg/1/000002\.png"):
        D3DGSReader().open(root)


def test_wrong_image_size_names_the_file(tmp_path):
    root = make_d3dgs(tmp_path)
    cv2.imwrite(str(root / "ims" / "0" / "000001.jpg"), np.zeros((H, W + 2, 3), np.uint8))
    recording = D3DGSReader().open(root)
    with pytest.raises(ValueError, match=r"ims/0/000001\.jpg is 18×12.*16×12"):
        list(recording.frames("cam_00", range(T)))


def test_ingest_auto_detects_and_stores_everything(tmp_path):
    from mmcsplat.pipeline.ingest import ingest

    root = make_d3dgs(tmp_path / "src")
    session = ingest(root, tmp_path / "session.zarr", progress=False)
    recording = D3DGSReader().open(root)
    assert session.provenance["format"] == "d3dgs" and session.heldout == ("cam_02",)
    assert session.camera_names == ("cam_00", "cam_01", "cam_02", "cam_03") and session.num_frames == T
    for expected in recording.cameras:
        stored = session.camera(expected.name)
        np.testing.assert_allclose(stored.K, expected.K)
        np.testing.assert_allclose(stored.world_to_camera, expected.world_to_camera)
        assert session.has("mask", expected.name) == (expected.name != "cam_02")
        for frame in recording.frames(expected.name, range(T)):
            stored_frame = session.frame(frame.t, expected.name)
            np.testing.assert_array_equal(stored_frame.rgb, frame.rgb)
            if frame.mask is None:
                assert stored_frame.mask is None
            else:
                np.testing.assert_array_equal(stored_frame.mask, _mask(frame.t, int(expected.name[4:])))


def test_missing_images_skipped_on_request(tmp_path):
    root = make_d3dgs(tmp_path)
    (root / "ims" / "1" / "000001.jpg").unlink()
    with pytest.warns(UserWarning, match=r"train_meta\.json: skipped 1 of 9 not found: .*ims/1/000001\.jpg"):
        recording = D3DGSReader(missing_frames="absent").open(root)
    assert recording.present("cam_01").tolist() == [True, False, True] and recording.present("cam_00").all()
    frames = list(recording.frames("cam_01", range(T)))
    assert [frame.t for frame in frames] == [0, 2] and all(frame.mask is not None for frame in frames)
