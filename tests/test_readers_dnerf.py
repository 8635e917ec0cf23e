"""The dnerf reader (D-NeRF / Blender layout, monocular) on small fixtures made here."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from mmcsplat.configuration.registry import default_registry
from mmcsplat.datasets.dnerf import DNeRFReader
from mmcsplat.scene.camera import look_at

W, H, ANGLE = 16, 12, 0.9
#: (split, time) of each frame; every frame has its own pose except where a test says otherwise.
FRAMES = {"train": [0.0, 1 / 3, 2 / 3, 1.0], "val": [0.5], "test": [1 / 3]}
TIMES = [0.0, 1 / 3, 0.5, 2 / 3, 1.0]


def _c2w_gl(angle: float) -> np.ndarray:
    """An OpenGL camera-to-world pose on a circle of radius 4 at height 1, looking at the origin."""
    centre = np.array([4 * np.cos(angle), 4 * np.sin(angle), 1.0])
    # OpenCV's right, down, forward rows are OpenGL's x, −y, −z camera axes.
    right, down, forward = look_at(centre, np.zeros(3))
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([right, -down, -forward], axis=1)
    c2w[:3, 3] = centre
    return c2w


def _rgba(seed: int) -> np.ndarray:
    """An RGBA image: opaque rectangle, transparent elsewhere, and one half-transparent pixel."""
    rgba = np.zeros((H, W, 4), np.uint8)
    rgba[..., :3] = np.random.default_rng(seed).integers(0, 256, (H, W, 3))
    rgba[3:9, 4:12, 3] = 255
    rgba[0, 0] = (200, 100, 50, 100)
    return rgba


def make_dnerf(root: Path, frames: dict[str, list[float]] = FRAMES) -> Path:
    """A D-NeRF folder: transforms files with extension-less file paths and RGBA PNGs."""
    seed = 0
    for split, times in frames.items():
        entries = []
        for index, time in enumerate(times):
            image = root / split / f"r_{index:03d}.png"
            image.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(image), cv2.cvtColor(_rgba(seed), cv2.COLOR_RGBA2BGRA))
            entries.append({"file_path": f"./{split}/r_{index:03d}", "time": time,
                            "transform_matrix": _c2w_gl(0.7 * seed).tolist()})
            seed += 1
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": ANGLE, "frames": entries}))
    return root


def _edit(root: Path, split: str, edit) -> None:
    path = root / f"transforms_{split}.json"
    document = json.loads(path.read_text())
    edit(document)
    path.write_text(json.dumps(document))


def test_registered_and_detects_only_its_layout(tmp_path):
    reader = default_registry().create("reader", "dnerf")
    assert isinstance(reader, DNeRFReader)
    assert reader.detect(make_dnerf(tmp_path / "dnerf"))
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "train_meta.json").write_text("{}")
    assert not reader.detect(tmp_path / "other")


def test_projection_matches_the_opengl_convention(tmp_path):
    recording = DNeRFReader().open(make_dnerf(tmp_path))
    focal = 0.5 * W / np.tan(0.5 * ANGLE)
    points = np.random.default_rng(1).uniform(-0.5, 0.5, (20, 3))
    for seed, camera in enumerate(recording.cameras):
        # Blender: the image plane spans [0, W] × [0, H] from pixel corners, y up, looking along −z;
        # shifting by half a pixel gives the pixel-centre coordinates mmcsplat and OpenCV use.
        gl = (np.linalg.inv(_c2w_gl(0.7 * seed)) @ np.c_[points, np.ones(len(points))].T).T
        expected = np.c_[W / 2 + focal * gl[:, 0] / -gl[:, 2] - 0.5, H / 2 - focal * gl[:, 1] / -gl[:, 2] - 0.5]
        np.testing.assert_allclose(camera.project(points), expected, atol=1e-9)
        assert np.all((points @ camera.R.T + camera.t)[:, 2] > 0)  # in front of the OpenCV camera


def test_monocular_cameras_present_times_and_heldout(tmp_path):
    recording = DNeRFReader().open(make_dnerf(tmp_path))
    names = [camera.name for camera in recording.cameras]
    assert names == ["train_000", "train_001", "train_002", "train_003", "val_000", "test_000"]
    assert recording.heldout == ("val_000", "test_000")
    np.testing.assert_allclose(recording.frame_times(), TIMES)
    assert recording.num_frames == 5 and recording.fps == pytest.approx(4.0)  # median spacing 1/4
    assert recording.has_masks
    present = np.array([recording.present(name) for name in names])
    np.testing.assert_array_equal(np.flatnonzero(present.sum(axis=0)), range(5))
    assert present.sum() == 6
    for name, t in (("train_002", 3), ("val_000", 2), ("test_000", 1)):
        np.testing.assert_array_equal(np.flatnonzero(recording.present(name)), [t])
        assert [frame.t for frame in recording.frames(name, range(5))] == [t]
    assert list(recording.frames("train_002", range(0, 3))) == []


def test_alpha_gives_mask_and_composites_over_black(tmp_path):
    recording = DNeRFReader().open(make_dnerf(tmp_path))
    (frame,) = recording.frames("val_000", range(5))
    rgba = _rgba(4)
    np.testing.assert_array_equal(frame.mask, rgba[..., 3] > 127)
    np.testing.assert_array_equal(frame.rgb[3:9, 4:12], rgba[3:9, 4:12, :3])
    assert not frame.rgb[H - 1, 0].any()  # transparent: black
    np.testing.assert_array_equal(frame.rgb[0, 0], np.round(np.array([200, 100, 50]) * 100 / 255))
    assert not frame.mask[0, 0]


def test_repeated_pose_is_one_camera_with_several_frames(tmp_path):
    root = make_dnerf(tmp_path, {"train": [0.0, 0.5, 1.0]})
    _edit(root, "train", lambda document: document["frames"][2].__setitem__("transform_matrix", document["frames"][0]["transform_matrix"]))
    recording = DNeRFReader().open(root)
    assert [camera.name for camera in recording.cameras] == ["train_000", "train_001"]
    np.testing.assert_array_equal(recording.present("train_000"), [True, False, True])
    _edit(root, "train", lambda document: document["frames"][2].__setitem__("time", 0.0))
    with pytest.raises(ValueError, match=r"transforms_train\.json: frames\[0\] and frames\[2\] have the same pose and time"):
        DNeRFReader().open(root)


def test_units_scale_translations(tmp_path):
    root = make_dnerf(tmp_path, {"train": [0.0]})
    metres, millimetres = DNeRFReader().open(root).cameras[0], DNeRFReader().open(root, units="mm").cameras[0]
    np.testing.assert_allclose(millimetres.center, metres.center * 1e-3)
    np.testing.assert_allclose(millimetres.R, metres.R)


@pytest.mark.parametrize("key", ["camera_angle_x", "frames"])
def test_missing_top_level_key_names_file(tmp_path, key):
    root = make_dnerf(tmp_path)
    _edit(root, "val", lambda document: document.pop(key))
    with pytest.raises(ValueError, match=rf"transforms_val\.json: missing key\(s\) '{key}'"):
        DNeRFReader().open(root)


def test_bad_frames_name_file_and_frame(tmp_path):
    root = make_dnerf(tmp_path)
    _edit(root, "train", lambda document: document["frames"][1].pop("time"))
    with pytest.raises(ValueError, match=r"transforms_train\.json: frames\[1\]: missing key\(s\) 'time'"):
        DNeRFReader().open(root)
    root = make_dnerf(tmp_path)
    _edit(root, "test", lambda document: document["frames"][0]["transform_matrix"][0].__setitem__(0, 2.0))
    with pytest.raises(ValueError, match=r"transforms_test\.json: frames\[0\]: 'transform_matrix' is not a rigid"):
        DNeRFReader().open(root)


def test_missing_image_and_calibration_are_refused_clearly(tmp_path):
    root = make_dnerf(tmp_path)
    (root / "train" / "r_002.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"transforms_train\.json: 1 of 4 not found: .*train/r_002\.png"):
        DNeRFReader().open(root)
    with pytest.raises(ValueError, match="--calibration is not supported"):
        DNeRFReader().open(make_dnerf(tmp_path / "ok"), calibration=tmp_path / "calibration.toml")


def test_ingest_stores_the_sparse_monocular_capture(tmp_path):
    from mmcsplat.pipeline.ingest import ingest
    from mmcsplat.storage.session import AbsentFrameError

    root = make_dnerf(tmp_path / "src")
    session = ingest(root, tmp_path / "session.zarr", progress=False)
    recording = DNeRFReader().open(root)
    assert session.provenance["format"] == "dnerf" and session.heldout == ("val_000", "test_000")
    assert session.num_frames == 5 and session.fps == pytest.approx(4.0)
    np.testing.assert_allclose(session.frame_times, TIMES)
    for expected in recording.cameras:
        np.testing.assert_array_equal(session.present(expected.name), recording.present(expected.name))
        stored = session.camera(expected.name)
        np.testing.assert_allclose(stored.K, expected.K)
        np.testing.assert_allclose(stored.world_to_camera, expected.world_to_camera, atol=1e-12)
        (frame,) = recording.frames(expected.name, range(5))
        np.testing.assert_array_equal(session.frame(frame.t, expected.name).rgb, frame.rgb)
        np.testing.assert_array_equal(session.frame(frame.t, expected.name).mask, frame.mask)
    with pytest.raises(AbsentFrameError):
        session.frame(0, "test_000")


def test_missing_images_skipped_on_request_keep_the_frame_indices(tmp_path):
    root = make_dnerf(tmp_path)
    (root / "train" / "r_001.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"transforms_train\.json: 1 of 4 not found"):
        DNeRFReader().open(root)
    with pytest.warns(UserWarning, match=r"skipped 1 of 4 not found: .*train/r_001\.png"):
        recording = DNeRFReader(missing_frames="absent").open(root)
    # train_001 had one image: left out; the time of the skipped image still counts.
    assert [camera.name for camera in recording.cameras] == ["train_000", "train_002", "train_003", "val_000", "test_000"]
    assert recording.heldout == ("val_000", "test_000") and recording.num_frames == len(TIMES)
    assert recording.present("train_002").tolist() == [False, False, False, True, False]
