"""The D-NeRF / Blender layout: a monocular capture, one camera pose per time step.

``transforms_{train,val,test}.json`` (val and test optional) each hold ``camera_angle_x`` (the horizontal
field of view, radians) and ``frames``, each with ``file_path`` (relative to the folder; ``.png`` is
appended when it names no image file), ``time`` (normalised to [0, 1]) and ``transform_matrix``
(camera-to-world, OpenGL camera axes: x right, y up, looking along −z).

Conventions chosen here:

- Cameras: OpenCV world-to-camera, obtained by flipping the camera's y and z axes. Each distinct pose of a
  split is a camera, ``train_000``, ``val_000``, … (numbered by first appearance; D-NeRF's poses are all
  distinct, so the number is the frame's position in the file), present only at the frame indices of
  its images; the recording's ``present`` says which. Cameras of val and test are held out.
- Intrinsics: fx = fy = 0.5·W / tan(0.5·camera_angle_x) and the principal point at the image centre as
  Blender renders it, which in mmcsplat's (OpenCV's) convention — pixel (u, v) centred at (u, v) — is
  ((W − 1)/2, (H − 1)/2). (NeRF-style loaders cast rays through (u − W/2), half a pixel off Blender's
  render; mmcsplat follows the renderer that made the images.)
- Images: RGBA; the mask is alpha > 127 and the colour is composited over black (rgb·alpha), the image a
  black-background render of the subject gives. D-NeRF's trainers composite over white instead; with
  the mask stored, a fit may choose its background.
- Time: frame indices are the sorted distinct times over all splits; the times are read as seconds (the
  clip lasts 1 s) and fps is 1 / the median spacing (1 for a single time).
- Missing images: an error listing every one, or with ``missing_frames="absent"`` skipped
  (:mod:`mmcsplat.datasets.posed_images`); the times of skipped images still count, so the frame indices
  do not depend on which files are present.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.datasets.posed_images import ALPHA_THRESHOLD, MISSING_FRAMES_PARAMETER, PosedImage, PosedImageRecording, missing_files, rigid_pose
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Reader
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import AUTO_UNITS, metres_per_unit
from mmcsplat.storage.capture_files import read_image, read_json

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
    missing: bool


@attrs.frozen
class DNeRFReader(Reader):
    """Reads the D-NeRF / Blender layout (the files give poses, times and splits); ``missing_frames`` is
    what a listed image that is not on disk does."""

    missing_frames: str = MISSING_FRAMES_PARAMETER

    def detect(self, source: Path) -> bool:
        """A folder with a ``transforms_train.json``."""
        return (Path(source) / "transforms_train.json").is_file()

    def open(self, source: Path, calibration: Path | None = None, units: str = AUTO_UNITS) -> PosedImageRecording:
        """Parse every split and check that each image exists. ``units`` is the unit of the poses'
        translations (``auto``: metres, as they stand); a separate calibration cannot apply to per-frame poses and is refused."""
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
            split_cameras, split_images, alpha = _parse_split(path, source, split, scale, self.missing_frames)
            has_masks = has_masks or (split == "train" and alpha)
            cameras += split_cameras
            images += split_images
            if split != "train":
                heldout += [camera.name for camera in split_cameras]
        times = np.unique(np.round([image.time for group in images for image in group], _DECIMALS))
        placed: dict[str, dict[int, PosedImage]] = {}
        for camera, group in zip(cameras, images):
            by_index: dict[int, _Image] = {}
            for image in group:
                t = int(np.searchsorted(times, round(image.time, _DECIMALS)))
                if t in by_index:
                    raise InputError(f"{image.json}: frames[{by_index[t].index}] and frames[{image.index}] have the same pose and time {image.time}")
                by_index[t] = image
            placed[camera.name] = {t: PosedImage(image.path, None, f"{image.json}: frames[{image.index}]")
                                   for t, image in by_index.items() if not image.missing}
        cameras = [camera for camera in cameras if placed[camera.name]]
        fps = 1.0 / float(np.median(np.diff(times))) if len(times) > 1 else 1.0
        return PosedImageRecording(source, cameras, {camera.name: placed[camera.name] for camera in cameras}, times, fps,
                                   [name for name in heldout if placed[name]], self._provenance(), alpha_mask=has_masks)

    @staticmethod
    def _provenance() -> dict[str, Any]:
        """The conventions applied (see the module's documentation)."""
        return {
            "format": "dnerf",
            "heldout_from": "transforms_val.json, transforms_test.json",
            "principal_point": "image centre as Blender renders it: ((W-1)/2, (H-1)/2) with pixel centres at integers",
            "rgb": "composited over black by alpha",
            "mask": f"alpha > {ALPHA_THRESHOLD}",
            "time": "source times read as seconds; fps = 1 / median spacing",
        }


def _parse_split(path: Path, source: Path, split: str, scale: float, missing_frames: str) -> tuple[list[Camera], list[list[_Image]], bool]:
    """The cameras of one transforms file, the images of each (missing ones marked, with
    ``missing_frames="absent"``), and whether its images carry alpha."""
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
    missing = missing_files(files, f"images listed in {path}", missing_frames)
    present = [file for file in files if file not in missing]
    if not present and split != "train":
        return [], [], False  # a held-out split with none of its images: nothing to evaluate on
    if not present:
        raise InputError(f"{path}: none of its images is on disk")
    # One image gives the split's size; every frame is checked against it when decoded.
    first, alpha = read_image(present[0])
    height, width = first.shape[:2]
    focal = 0.5 * width / np.tan(0.5 * angle)
    K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    poses: dict[tuple[float, ...], int] = {}
    cameras: list[Camera] = []
    images: list[list[_Image]] = []
    for index, (frame, file) in enumerate(zip(frames, files)):
        where = f"{path}: frames[{index}]"
        c2w = rigid_pose(where, frame["transform_matrix"])
        key = tuple(np.round(c2w[:3], _DECIMALS).ravel().tolist())
        if key not in poses:
            poses[key] = len(cameras)
            c2w_cv = c2w @ GL_TO_CV
            R = c2w_cv[:3, :3].T
            cameras.append(Camera(name=f"{split}_{len(cameras):03d}", width=width, height=height, K=K, R=R,
                                  t=-R @ (c2w_cv[:3, 3] * scale)))
            images.append([])
        images[poses[key]].append(_Image(file, _number(where, "time", frame["time"]), path, index, file in missing))
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
