"""The D-NeRF / Blender layout: a monocular capture, one camera pose per time step.

``transforms_{train,val,test}.json`` (val and test optional) each hold ``camera_angle_x`` (the horizontal
field of view, radians) and ``frames``, each with ``file_path`` (relative to the folder; ``.png`` is
appended when it names no image file), ``time`` (normalised to [0, 1]) and ``transform_matrix``
(camera-to-world, OpenGL camera axes: x right, y up, looking along −z).

Conventions chosen here:

- Cameras: OpenCV world-to-camera, obtained by flipping the camera's y and z axes. Each distinct pose of a
  split is a camera, ``train_000``, ``val_000``, … (numbered by first appearance; D-NeRF's poses are all
  distinct, so the number is the frame's position in the file), present only at the frame indices of
  its images; :meth:`DNeRFRecording.present` says which. Cameras of val and test are held out.
- Intrinsics: fx = fy = 0.5·W / tan(0.5·camera_angle_x) and the principal point at the image centre as
  Blender renders it, which in mmcsplat's (OpenCV's) convention — pixel (u, v) centred at (u, v) — is
  ((W − 1)/2, (H − 1)/2). (NeRF-style loaders cast rays through (u − W/2), half a pixel off Blender's
  render; mmcsplat follows the renderer that made the images.)
- Images: RGBA; the mask is alpha > 127 and the colour is composited over black (rgb·alpha), the image a
  black-background render of the subject gives. D-NeRF's trainers composite over white instead; with
  the mask stored, a fit may choose its background.
- Time: frame indices are the sorted distinct times over all splits; the times are read as seconds (the
  clip lasts 1 s) and fps is 1 / the median spacing (1 for a single time).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Reader, RecordedFrame, Recording
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import metres_per_unit
from mmcsplat.storage.capture_files import read_image, read_json, require_files

SPLITS = ("train", "val", "test")
_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".bmp", ".webp"}
_DECIMALS = 9  # times and poses equal to this many decimals are the same
#: OpenGL camera axes (y up, looking along −z) to OpenCV's (y down, looking along +z).
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@attrs.frozen
class _Image:
    """One frame of the source: its file, time and split."""

    path: Path
    time: float
    json: Path
    index: int


@attrs.frozen
class DNeRFReader(Reader):
    """Reads the D-NeRF / Blender layout (no parameters: the files give poses, times and splits)."""

    def detect(self, source: Path) -> bool:
        """A folder with a ``transforms_train.json``."""
        return (Path(source) / "transforms_train.json").is_file()

    def open(self, source: Path, calibration: Path | None = None, units: str = "m") -> DNeRFRecording:
        """Parse every split and check that each image exists. ``units`` is the unit of the poses'
        translations; a separate calibration cannot apply to per-frame poses and is refused."""
        source = Path(source)
        if calibration is not None:
            raise InputError(f"dnerf source {source}: the poses come from transforms_*.json; --calibration is not supported")
        scale = metres_per_unit(units)
        cameras: list[Camera] = []
        images: list[list[_Image]] = []
        heldout: list[str] = []
        has_masks = False
        for split in SPLITS:
            path = source / f"transforms_{split}.json"
            if split != "train" and not path.is_file():
                continue
            split_cameras, split_images, alpha = _parse_split(path, source, split, scale)
            has_masks = has_masks or (split == "train" and alpha)
            cameras += split_cameras
            images += split_images
            if split != "train":
                heldout += [camera.name for camera in split_cameras]
        return DNeRFRecording(source, cameras, images, heldout, has_masks)


def _parse_split(path: Path, source: Path, split: str, scale: float) -> tuple[list[Camera], list[list[_Image]], bool]:
    """The cameras of one transforms file, the images of each, and whether its images carry alpha."""
    document = read_json(path, ("camera_angle_x", "frames"))
    frames = document["frames"]
    if not isinstance(frames, list) or not frames:
        raise InputError(f"{path}: 'frames' must be a non-empty list")
    angle = _number(path, "camera_angle_x", document["camera_angle_x"])
    if not 0 < angle < np.pi:
        raise InputError(f"{path}: camera_angle_x must be in (0, π) radians, got {angle}")
    files = []
    for index, frame in enumerate(frames):
        where = f"{path}: frames[{index}]"
        if not isinstance(frame, dict):
            raise InputError(f"{where}: expected an object with file_path, time and transform_matrix")
        missing = [key for key in ("file_path", "time", "transform_matrix") if key not in frame]
        if missing:
            raise InputError(f"{where}: missing key(s) {', '.join(repr(key) for key in missing)}")
        files.append(_image_path(source, frame["file_path"], where))
    require_files(files, f"image listed in {path}:")
    # One image gives the split's size; every frame is checked against it when decoded.
    first, alpha = read_image(files[0])
    height, width = first.shape[:2]
    focal = 0.5 * width / np.tan(0.5 * angle)
    K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    poses: dict[tuple[float, ...], int] = {}
    cameras: list[Camera] = []
    images: list[list[_Image]] = []
    for index, (frame, file) in enumerate(zip(frames, files)):
        where = f"{path}: frames[{index}]"
        c2w = _pose(where, frame["transform_matrix"])
        key = tuple(np.round(c2w[:3], _DECIMALS).ravel().tolist())
        if key not in poses:
            poses[key] = len(cameras)
            c2w_cv = c2w @ GL_TO_CV
            R = c2w_cv[:3, :3].T
            cameras.append(Camera(name=f"{split}_{len(cameras):03d}", width=width, height=height, K=K, R=R,
                                  t=-R @ (c2w_cv[:3, 3] * scale)))
            images.append([])
        images[poses[key]].append(_Image(file, _number(where, "time", frame["time"]), path, index))
    return cameras, images, alpha is not None


def _image_path(source: Path, file_path: Any, where: str) -> Path:
    """The image file of ``file_path``, with ``.png`` appended when it names no image file."""
    if not isinstance(file_path, str) or not file_path:
        raise InputError(f"{where}: 'file_path' must be a non-empty string, got {file_path!r}")
    path = source / file_path
    return path if path.suffix.lower() in _IMAGE_SUFFIXES else path.with_name(path.name + ".png")


def _number(where: Path | str, key: str, value: Any) -> float:
    """``value`` as a finite float, or an error naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise InputError(f"{where}: {key!r} must be a finite number, got {value!r}")
    return float(value)


def _pose(where: str, value: Any) -> np.ndarray:
    """A rigid 4×4 camera-to-world matrix (a 3×4 one is completed)."""
    try:
        matrix = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: 'transform_matrix' must be a 4×4 matrix of numbers") from None
    if matrix.shape not in ((4, 4), (3, 4)) or not np.all(np.isfinite(matrix)):
        raise InputError(f"{where}: 'transform_matrix' must be a finite 4×4 matrix, got shape {matrix.shape}")
    rotation = matrix[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-5) or np.linalg.det(rotation) < 0:
        raise InputError(f"{where}: 'transform_matrix' is not a rigid transform (its 3×3 part is not a rotation)")
    return np.vstack([matrix[:3], [0.0, 0.0, 0.0, 1.0]])


class DNeRFRecording(Recording):
    """An opened D-NeRF capture: sparse, each camera present at the times of its images."""

    def __init__(self, source: Path, cameras: list[Camera], images: list[list[_Image]], heldout: list[str],
                 has_masks: bool) -> None:
        self.source = source
        self.cameras = cameras
        self.heldout = tuple(heldout)
        self.has_masks = has_masks
        self._times = np.unique(np.round([image.time for group in images for image in group], _DECIMALS))
        self.num_frames = len(self._times)
        self.fps = 1.0 / float(np.median(np.diff(self._times))) if self.num_frames > 1 else 1.0
        self._frames: dict[str, dict[int, _Image]] = {}
        for camera, group in zip(cameras, images):
            by_index = self._frames[camera.name] = {}
            for image in group:
                t = int(np.searchsorted(self._times, round(image.time, _DECIMALS)))
                if t in by_index:
                    other = by_index[t]
                    raise InputError(f"{image.json}: frames[{other.index}] and frames[{image.index}] have the same pose "
                                     f"and time {image.time}")
                by_index[t] = image
        self._cameras = {camera.name: camera for camera in cameras}

    def _camera_frames(self, camera: str) -> dict[int, _Image]:
        try:
            return self._frames[camera]
        except KeyError:
            raise KeyError(f"dnerf source {self.source} has no camera {camera!r}") from None

    def present(self, camera: str) -> np.ndarray:
        """True only at the frame indices where ``camera`` has an image."""
        present = np.zeros(self.num_frames, dtype=bool)
        present[list(self._camera_frames(camera))] = True
        return present

    def frame_times(self) -> np.ndarray:
        """The distinct source times, read as seconds."""
        return self._times.copy()

    def frames(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        """Decode ``camera``'s images at ``indices``: colour composited over black, mask from alpha."""
        by_index = self._camera_frames(camera)
        expected = (self._cameras[camera].height, self._cameras[camera].width)
        for t in indices:
            image = by_index.get(t)
            if image is None:
                continue
            rgb, alpha = read_image(image.path)
            if rgb.shape[:2] != expected:
                raise InputError(f"image {image.path} is {rgb.shape[1]}×{rgb.shape[0]}, but the first image of "
                                 f"{image.json.name} is {expected[1]}×{expected[0]}")
            mask = None
            if alpha is not None:
                mask = alpha > 127
                rgb = np.round(rgb * (alpha[:, :, None] / 255.0)).astype(np.uint8)
            yield RecordedFrame(t=t, rgb=rgb, mask=mask)

    def describe(self) -> dict[str, Any]:
        """The format, the source and the conventions applied (see the module's documentation)."""
        return {
            "format": "dnerf",
            "source": str(self.source),
            "heldout_from": "transforms_val.json, transforms_test.json",
            "principal_point": "image centre as Blender renders it: ((W-1)/2, (H-1)/2) with pixel centres at integers",
            "rgb": "composited over black by alpha",
            "mask": "alpha > 127",
            "time": "source times read as seconds; fps = 1 / median spacing",
        }
