"""The colmap reader (a sparse model, text or binary, plus images/) on small fixtures made here."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from mmcsplat.configuration.registry import default_registry
from mmcsplat.datasets.colmap import ColmapReader
from mmcsplat.pipeline.ingest import detect_format
from mmcsplat.scene.camera import look_at

W, H = 16, 12
MODEL_IDS = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1, "SIMPLE_RADIAL": 2, "RADIAL": 3, "OPENCV": 4, "OPENCV_FISHEYE": 5, "FULL_OPENCV": 6,
             "SIMPLE_RADIAL_FISHEYE": 8, "RADIAL_FISHEYE": 9}
#: One camera per model: (model, COLMAP params with the principal point in COLMAP's pixel coordinates).
MODELS = [
    ("SIMPLE_PINHOLE", (20.0, 8.0, 6.0)),
    ("PINHOLE", (20.0, 21.0, 7.7, 5.9)),
    ("SIMPLE_RADIAL", (19.0, 8.1, 6.2, 0.03)),
    ("RADIAL", (18.0, 7.9, 5.8, 0.02, -0.01)),
    ("OPENCV", (22.0, 23.0, 8.3, 6.4, 0.04, -0.02, 0.001, -0.002)),
    ("OPENCV_FISHEYE", (12.0, 12.5, 8.2, 6.1, 0.05, -0.02, 0.01, -0.002)),
    ("SIMPLE_RADIAL_FISHEYE", (11.0, 7.8, 6.3, -0.04)),
    ("RADIAL_FISHEYE", (11.5, 8.0, 6.0, 0.03, -0.01)),
]
CENTRES = [(4.0, 0.0, 1.0), (0.0, 4.0, 1.5), (-3.0, -3.0, 0.5), (2.0, -3.5, 2.0), (-4.0, 1.0, 1.0), (3.0, 3.0, 0.8), (-1.0, -4.0, 1.2),
           (1.0, 4.5, 0.3)]
POINT = np.array([0.1, -0.2, 0.3])


def _pose(centre) -> tuple[np.ndarray, np.ndarray]:
    R = look_at(centre, (0.0, 0.0, 0.0))
    return R, -R @ np.asarray(centre)


def _qvec(R: np.ndarray) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z) of a rotation matrix."""
    trace = np.trace(R)
    if trace > 0:
        s = 2 * np.sqrt(1 + trace)
        q = (0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s)
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * np.sqrt(1 + R[i, i] - R[j, j] - R[k, k])
        q = [0.0] * 4
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    return tuple(float(value) for value in q)


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)


def write_model(folder: Path, kind: str, cameras: list[tuple[int, str, tuple]], images: list[tuple[int, tuple, tuple, int, str]]) -> None:
    """``cameras.{kind}`` and ``images.{kind}`` of (id, model, params) and (id, qvec, tvec, camera id, name)."""
    folder.mkdir(parents=True, exist_ok=True)
    if kind == "txt":
        lines = ["# Camera list with one line of data per camera:"]
        lines += [f"{cid} {model} {W} {H} " + " ".join(repr(float(p)) for p in params) for cid, model, params in cameras]
        (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
        lines = ["# Image list with two lines of data per image:", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
        for number, (iid, qvec, tvec, cid, name) in enumerate(images):
            lines.append(" ".join(repr(float(v)) if isinstance(v, float) else str(v) for v in (iid, *qvec, *tvec, cid, name)))
            lines.append("" if number % 2 else "1.5 2.5 -1 3.5 4.5 7")  # points may be empty
        (folder / "images.txt").write_text("\n".join(lines) + "\n")
        return
    data = struct.pack("<Q", len(cameras))
    for cid, model, params in cameras:
        data += struct.pack("<iiQQ", cid, MODEL_IDS[model], W, H) + struct.pack(f"<{len(params)}d", *params)
    (folder / "cameras.bin").write_bytes(data)
    data = struct.pack("<Q", len(images))
    for number, (iid, qvec, tvec, cid, name) in enumerate(images):
        points = [] if number % 2 else [(1.5, 2.5, -1), (3.5, 4.5, 7)]
        data += struct.pack("<i4d3di", iid, *qvec, *tvec, cid) + name.encode() + b"\0" + struct.pack("<Q", len(points))
        data += b"".join(struct.pack("<ddq", *point) for point in points)
    (folder / "images.bin").write_bytes(data)


def make_static(root: Path, kind: str) -> Path:
    """A still scene: one image for each of :data:`MODELS`, each with its own COLMAP camera of that model."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    images = []
    for index, centre in enumerate(CENTRES):
        cv2.imwrite(str(root / "images" / f"shot_{index}.png"), cv2.cvtColor(_image(index), cv2.COLOR_RGB2BGR))
        R, t = _pose(centre)
        images.append((index + 1, _qvec(R), tuple(t), 10 + index, f"shot_{index}.png"))
    write_model(root / "sparse" / "0", kind, [(10 + index, model, params) for index, (model, params) in enumerate(MODELS)], images)
    return root


def _colmap_pixel(model: str, params: tuple, R: np.ndarray, t: np.ndarray, point: np.ndarray) -> np.ndarray:
    """COLMAP's projection of ``point`` (pixel centres at +0.5), shifted to pixel indices (centres at integers)."""
    x, y, z = R @ point + t
    u, v = x / z, y / z
    r2 = u * u + v * v
    if model.endswith("FISHEYE"):  # θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸), θ = atan(r)
        fx, fy, cx, cy, *ks = params if model == "OPENCV_FISHEYE" else (params[0], *params)
        theta = np.arctan(np.sqrt(r2))
        scale = theta * (1 + sum(k * theta ** (2 * i + 2) for i, k in enumerate(ks))) / np.sqrt(r2)
        return np.array([fx * u * scale + cx - 0.5, fy * v * scale + cy - 0.5])
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        f, cx, cy, *ks = params
        fx = fy = f
        k1, k2 = (ks + [0.0, 0.0])[:2]
        du, dv = u * (k1 * r2 + k2 * r2 * r2), v * (k1 * r2 + k2 * r2 * r2)
    else:
        fx, fy, cx, cy, *rest = params
        k1, k2, p1, p2 = (rest + [0.0] * 4)[:4]
        radial = k1 * r2 + k2 * r2 * r2
        du = u * radial + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
        dv = v * radial + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
    return np.array([fx * (u + du) + cx - 0.5, fy * (v + dv) + cy - 0.5])


def test_registered_and_detects_only_its_layout(tmp_path):
    reader = default_registry().create("reader", "colmap")
    assert isinstance(reader, ColmapReader)
    root = make_static(tmp_path / "colmap", "bin")
    assert reader.detect(root) and detect_format(root) == "colmap"
    (tmp_path / "no_images").mkdir()
    (tmp_path / "no_images" / "sparse").symlink_to(root / "sparse")
    assert not reader.detect(tmp_path / "no_images")
    (tmp_path / "images_only" / "images" / "cam_0").mkdir(parents=True)
    assert not reader.detect(tmp_path / "images_only")


@pytest.mark.parametrize("kind", ["txt", "bin"])
def test_cameras_match_the_known_ones_and_project_alike(tmp_path, kind):
    recording = ColmapReader().open(make_static(tmp_path, kind))
    assert [camera.name for camera in recording.cameras] == [f"shot_{index}" for index in range(len(MODELS))]
    assert recording.num_frames == 1 and recording.describe()["layout"] == "static"
    assert recording.describe()["model_files"] == {"txt": "text", "bin": "binary"}[kind]
    for index, ((model, params), centre, camera) in enumerate(zip(MODELS, CENTRES, recording.cameras)):
        R, t = _pose(centre)
        np.testing.assert_allclose(camera.R, R, atol=1e-6)
        np.testing.assert_allclose(camera.t, t, atol=1e-6)
        fx, fy, cx, cy = (params[0], params[0], params[1], params[2]) if model.startswith(("SIMPLE", "RADIAL")) else params[:4]
        assert camera.fisheye == model.endswith("FISHEYE")
        np.testing.assert_allclose(camera.K, [[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1]], atol=1e-6)
        np.testing.assert_allclose(camera.project(POINT[None])[0], _colmap_pixel(model, params, R, t, POINT), atol=1e-6)
        (frame,) = recording.frames(camera.name, range(1))
        np.testing.assert_array_equal(frame.rgb, _image(index))
    assert recording.cameras[0].distortion.size == 0 and recording.cameras[2].distortion.tolist() == [0.03, 0.0, 0.0, 0.0]


@pytest.mark.parametrize("kind", ["txt", "bin"])
def test_ingest_through_the_cli(tmp_path, kind):
    from mmcsplat.cli import main
    from mmcsplat.storage.session import SessionReader

    root = make_static(tmp_path / "src", kind)
    assert main(["ingest", str(root), str(tmp_path / "s.zarr"), "--no-progress"]) == 0
    session = SessionReader(tmp_path / "s.zarr")
    assert session.provenance["format"] == "colmap" and session.num_frames == 1
    for index, centre in enumerate(CENTRES[:2]):  # the undistorted ones keep K
        stored = session.camera(f"shot_{index}")
        np.testing.assert_allclose(stored.world_to_camera[:3], np.c_[_pose(centre)], atol=1e-6)
        np.testing.assert_array_equal(session.frame(0, f"shot_{index}").rgb, _image(index))


def make_video(root: Path, kind: str, frames: int = 3) -> Path:
    """A fixed rig of two cameras, images/CAM/NNNN.png, the model registering frames 1 and 2 of each."""
    images = []
    for index, name in enumerate(("camA", "camB")):
        (root / "images" / name).mkdir(parents=True, exist_ok=True)
        for number in range(1, frames + 1):
            cv2.imwrite(str(root / "images" / name / f"{number:04d}.png"), cv2.cvtColor(_image(10 * index + number), cv2.COLOR_RGB2BGR))
        R, t = _pose(CENTRES[index])
        images += [(2 * index + number, _qvec(R), tuple(t), 1 + index, f"{name}/{number:04d}.png") for number in (1, 2)]
    write_model(root / "sparse" / "0", kind, [(1, "PINHOLE", MODELS[1][1]), (2, "OPENCV", MODELS[4][1])], images)
    return root


@pytest.mark.parametrize("kind", ["txt", "bin"])
def test_video_layout_one_camera_per_folder(tmp_path, kind):
    root = make_video(tmp_path, kind)
    recording = ColmapReader(fps=25).open(root)
    assert [camera.name for camera in recording.cameras] == ["camA", "camB"]
    assert recording.num_frames == 3 and recording.fps == 25 and recording.describe()["layout"] == "video"
    np.testing.assert_allclose(recording.frame_times(), [0.0, 0.04, 0.08])
    np.testing.assert_allclose(recording.cameras[1].center, CENTRES[1], atol=1e-6)
    assert [frame.t for frame in recording.frames("camB", range(3))] == [0, 1, 2]
    np.testing.assert_array_equal(next(recording.frames("camB", range(2, 3))).rgb, _image(13))
    static = ColmapReader(layout="static").open(root)
    assert [camera.name for camera in static.cameras] == ["camA_0001", "camA_0002", "camB_0001", "camB_0002"]


def test_video_layout_needs_one_pose_per_folder(tmp_path):
    root = make_video(tmp_path, "txt")
    lines = (root / "sparse" / "0" / "images.txt").read_text().splitlines()
    fields = lines[4].split()  # camA/0002.png's pose
    fields[5] = str(float(fields[5]) + 0.1)
    lines[4] = " ".join(fields)
    (root / "sparse" / "0" / "images.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"images\.txt: images 'camA/0001\.png' and 'camA/0002\.png' of camera folder 'camA' differ"):
        ColmapReader().open(root)
    assert len(ColmapReader(layout="static").open(root).cameras) == 4


def test_unsupported_model_names_file_and_model(tmp_path):
    root = make_static(tmp_path / "txt", "txt")
    path = root / "sparse" / "0" / "cameras.txt"
    full = "FULL_OPENCV 16 12 20.0 21.0 7.7 5.9 0.1 0.0 0.0 0.0 0.0 0.0 0.0 0.0"
    path.write_text(path.read_text().replace("PINHOLE 16 12 20.0 21.0 7.7 5.9", full))
    with pytest.raises(ValueError, match=r"cameras\.txt: line 3: camera 11: camera model FULL_OPENCV is not supported"):
        ColmapReader().open(root)
    root = make_static(tmp_path / "bin", "bin")
    write_model(root / "sparse" / "0", "bin", [(10, "FULL_OPENCV", (20.0, 21.0, 7.7, 5.9, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))], [])
    with pytest.raises(ValueError, match=r"cameras\.bin: camera 10: camera model FULL_OPENCV is not supported"):
        ColmapReader().open(root)


@pytest.mark.parametrize("kind", ["txt", "bin"])
def test_missing_image_names_the_model_file(tmp_path, kind):
    root = make_static(tmp_path, kind)
    (root / "images" / "shot_3.png").unlink()
    with pytest.raises(FileNotFoundError, match=rf"images listed in .*images\.{kind}: 1 of \d+ not found: .*shot_3\.png"):
        ColmapReader().open(root)


def test_malformed_models_name_the_file(tmp_path):
    root = make_static(tmp_path / "txt", "txt")
    path = root / "sparse" / "0" / "images.txt"
    path.write_text(path.read_text().replace("shot_2.png", ""))
    with pytest.raises(ValueError, match=r"images\.txt: line \d+: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"):
        ColmapReader().open(root)
    cameras = root / "sparse" / "0" / "cameras.txt"
    cameras.write_text(cameras.read_text().replace("RADIAL 16 12 18.0", "RADIAL 16 12"))
    with pytest.raises(ValueError, match=r"cameras\.txt: line \d+: camera 13 \(RADIAL\) needs 5 finite parameters, got 4"):
        ColmapReader().open(root)
    root = make_static(tmp_path / "bin", "bin")
    images = root / "sparse" / "0" / "images.bin"
    complete = images.read_bytes()
    images.write_bytes(complete[:-30])
    with pytest.raises(ValueError, match=r"images\.bin: truncated at byte \d+"):
        ColmapReader().open(root)
    images.write_bytes(complete + b"junk")
    with pytest.raises(ValueError, match=r"images\.bin: 4 unexpected bytes after the last entry"):
        ColmapReader().open(root)
    write_model(root / "sparse" / "0", "bin", [(99, "PINHOLE", MODELS[1][1])], [(1, (1.0, 0, 0, 0), (0.0, 0, 4), 10, "shot_0.png")])
    with pytest.raises(ValueError, match=r"images\.bin: image 'shot_0\.png' uses camera 10, which cameras\.bin lacks"):
        ColmapReader().open(root)
