"""nerfstudio's ``transforms.json`` layout: posed images, each with pinhole intrinsics and OpenCV distortion.

``transforms.json`` holds optional top-level intrinsics — ``fl_x``, ``fl_y``, ``cx``, ``cy``, ``w``, ``h``,
the distortion ``k1``, ``k2``, ``k3``, ``k4``, ``p1``, ``p2`` and ``camera_model`` — and ``frames``, each
with ``file_path`` (relative to the folder), ``transform_matrix`` (camera-to-world, OpenGL camera axes: x
right, y up, looking along −z), optionally ``mask_path`` and its own intrinsics, which override the top
level key by key. ``val_filenames`` / ``test_filenames`` (lists of file paths) mark held-out images.

Conventions chosen here:

- Camera models: ``OPENCV`` (the default when none is given) and ``PINHOLE``; both read the distortion
  keys, as nerfstudio does. A non-zero ``k4`` (nerfstudio's r⁸ term, which OpenCV's pinhole model lacks)
  is refused; the others become OpenCV's (k1, k2, p1, p2[, k3]): none when all are zero, k3 only when it
  is non-zero. ``OPENCV_FISHEYE`` is OpenCV's fisheye model with ``k1`` … ``k4``; a non-zero ``p1`` or
  ``p2``, which it has no place for, is refused. ``EQUIRECTANGULAR`` and any other model are refused.
- Principal point: nerfstudio (like COLMAP) puts a pixel's centre at (u + 0.5, v + 0.5) — its rays pass
  through pixel coordinates offset by half a pixel — whereas mmcsplat's pixel (u, v) is centred at (u, v),
  so cx and cy are read minus 0.5 (the inverse of ``mmcsplat export --transforms``).
- Cameras: OpenCV world-to-camera, obtained by flipping the camera's y and z axes
  (:data:`mmcsplat.datasets.dnerf.GL_TO_CV`). A frame may name its camera with a ``camera`` key (a string
  or a whole number; then every frame must, and a camera's frames must agree on pose and intrinsics);
  otherwise frames with the same pose, intrinsics, size and distortion (to 9 decimals) are one camera.
  When every camera has exactly one image, cameras are named after the image's file stem (when those are
  unique), else ``cam_000``, ``cam_001``, … in order of first appearance.
- Time: a frame's ``time`` key, or else its ``timestamp`` key, read as seconds (then every frame needs
  one); frame indices are the sorted distinct times and fps is 1 / their median spacing. Without times,
  every camera must have the same number of images: frame k of a camera is its k-th image in natural
  order of ``file_path`` (one image per camera: a static capture of one frame) and the ``fps`` parameter
  gives the frame rate. One camera with two images at one frame index is an error.
- World: ``applied_transform`` (written by ``ns-process-data``) records the transform already applied to
  the poses in the file; the poses are used as written and it is not applied again, only recorded in the
  session's provenance. nerfstudio's dataparser_transforms.json (its own re-centring) is not read.
- Images: RGB is read as stored (an alpha channel is dropped); ``mask_path`` gives a subject mask (values
  above half the range, or the ones of a 0/1 image); with any ``mask_path``, every frame needs one.
- Held out: a camera whose images are all listed in ``val_filenames`` or ``test_filenames``.
- Missing images (or masks): an error listing every one, or with ``missing_frames="absent"`` skipped
  (:mod:`mmcsplat.datasets.posed_images`); frames are placed before skipping, so the others keep their
  frame indices, and a camera left without images is left out.
- A separate ``--calibration`` is refused: the file gives every pose.

:class:`~mmcsplat.datasets.posed_images.PosedImageRecording`, the recording of posed images at frame
indices, is shared with the ``colmap``, ``dnerf`` and ``d3dgs`` readers.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.datasets.dnerf import GL_TO_CV
from mmcsplat.datasets.frame_rate import FPS_PARAMETER, stated_or_assumed
from mmcsplat.datasets.posed_images import MISSING_FRAMES_PARAMETER, PosedImage, PosedImageRecording, finite_matrix, missing_files, rigid_pose
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Reader
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import AUTO_UNITS, metres_per_unit
from mmcsplat.storage.camera_names import natural_key
from mmcsplat.storage.capture_files import read_json

#: Where mmcsplat's pixel centre (u, v) lies in nerfstudio's (and COLMAP's) pixel coordinates.
PIXEL_CENTRE = 0.5
_MODELS = ("OPENCV", "PINHOLE", "OPENCV_FISHEYE")
_INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
_DECIMALS = 9  # times, poses and intrinsics equal to this many decimals are the same


@attrs.frozen
class _Frame:
    """One parsed entry of ``frames``."""

    index: int
    image: PosedImage
    camera: str | None
    time: float | None
    K: np.ndarray
    size: tuple[int, int]
    distortion: np.ndarray
    fisheye: bool
    c2w: np.ndarray

    @property
    def where(self) -> str:
        return self.image.listed

    def key(self) -> tuple[float, ...]:
        """What makes two frames one camera: pose, intrinsics, size and lens, rounded."""
        values = np.concatenate([self.c2w[:3].ravel(), self.K.ravel(), self.size, [self.fisheye], self.distortion])
        return tuple(np.round(values, _DECIMALS).tolist())


@attrs.frozen
class NerfstudioReader(Reader):
    """Reads nerfstudio's ``transforms.json``; ``fps`` is the frame rate when the frames carry no time,
    ``missing_frames`` what a listed image that is not on disk does."""

    fps: float | None = FPS_PARAMETER
    missing_frames: str = MISSING_FRAMES_PARAMETER

    def detect(self, source: Path) -> bool:
        """A folder with a ``transforms.json`` and no ``transforms_train.json`` (that is the dnerf layout)."""
        source = Path(source)
        return (source / "transforms.json").is_file() and not (source / "transforms_train.json").is_file()

    def open(self, source: Path, calibration: Path | None = None, units: str = AUTO_UNITS) -> PosedImageRecording:
        """Parse ``transforms.json`` and check that every image and mask exists (or skip those that do not,
        with ``missing_frames="absent"``). ``units`` is the unit of
        the poses' translations (``auto``: metres, as they stand); a separate calibration cannot apply to per-frame poses and is refused."""
        source = Path(source)
        if calibration is not None:
            raise InputError(f"nerfstudio source {source}: the poses come from transforms.json; --calibration is not supported")
        scale = metres_per_unit(units)
        path = source / "transforms.json"
        document = read_json(path, ("frames",))
        entries = document["frames"]
        if not isinstance(entries, list) or not entries:
            raise InputError(f"{path}: 'frames' must be a non-empty list")
        applied = _applied_transform(path, document.get("applied_transform"))
        frames = [_parse_frame(path, source, document, index, entry) for index, entry in enumerate(entries)]
        with_masks = [frame for frame in frames if frame.image.mask is not None]
        if with_masks and len(with_masks) != len(frames):
            lacking = next(frame for frame in frames if frame.image.mask is None)
            raise InputError(f"{lacking.where}: no 'mask_path', but other frames have masks (give every frame one, or none)")
        missing = missing_files([frame.image.path for frame in frames], f"images listed in {path}", self.missing_frames)
        missing |= missing_files([frame.image.mask for frame in with_masks], f"masks listed in {path}", self.missing_frames)
        groups = _group_cameras(path, frames)
        images, times, fps = _place_frames(path, groups, self.fps)
        heldout = _heldout(path, document, groups)
        images = {name: {t: image for t, image in by_index.items() if not {image.path, image.mask} & missing} for name, by_index in images.items()}
        images = {name: by_index for name, by_index in images.items() if by_index}
        if not images:
            raise InputError(f"{path}: none of its images is on disk")
        cameras = [_camera(name, group[0], scale) for name, group in groups.items() if name in images]
        heldout = [name for name in heldout if name in images]
        provenance = {
            "format": "nerfstudio",
            "principal_point": "cx, cy minus 0.5: nerfstudio's pixel centres are at +0.5, mmcsplat's at integers",
            "axes": "transform_matrix camera-to-world with OpenGL camera axes; y and z flipped to OpenCV's",
            "time": "time or timestamp keys as seconds" if any(frame.time is not None for frame in frames)
                    else f"none in the file: image k of each camera is frame k at {fps:g} fps",
            "applied_transform": None if applied is None else applied.tolist(),
            "applied_transform_use": "recorded only: the poses in the file already include it",
            "missing_images_skipped": sorted(str(file) for file in missing),
        }
        return PosedImageRecording(source, cameras, images, times, fps, heldout, provenance)


def _number(where: str, key: str, value: Any) -> float:
    """``value`` as a finite float, or an error naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise InputError(f"{where}: {key!r} must be a finite number, got {value!r}")
    return float(value)


def _applied_transform(path: Path, value: Any) -> np.ndarray | None:
    """The top-level ``applied_transform`` as a finite 3×4 matrix (4×4 accepted), or None when absent."""
    if value is None:
        return None
    return finite_matrix(str(path), "applied_transform", value, "3×4")[:3]


def _file(source: Path, where: str, key: str, value: Any) -> Path:
    """The file a ``file_path`` or ``mask_path`` names, relative to the folder."""
    if not isinstance(value, str) or not value:
        raise InputError(f"{where}: {key!r} must be a non-empty string, got {value!r}")
    return source / value


def _parse_frame(path: Path, source: Path, document: Mapping[str, Any], index: int, entry: Any) -> _Frame:
    """One entry of ``frames``, its intrinsics completed from the top level."""
    where = f"{path}: frames[{index}]"
    if not isinstance(entry, dict):
        raise InputError(f"{where}: expected an object with file_path and transform_matrix")
    missing = [key for key in ("file_path", "transform_matrix") if key not in entry]
    if missing:
        raise InputError(f"{where}: missing key(s) {', '.join(repr(key) for key in missing)}")
    merged = {key: entry.get(key, document.get(key)) for key in (*_INTRINSICS, *_DISTORTION, "camera_model")}
    model = merged["camera_model"] if merged["camera_model"] is not None else "OPENCV"
    if model not in _MODELS:
        raise InputError(f"{where}: camera_model {model!r} is not supported (only {' and '.join(_MODELS)}; "
                         "undistort panoramic images first)")
    absent = [key for key in _INTRINSICS if merged[key] is None]
    if absent:
        raise InputError(f"{where}: missing intrinsics {', '.join(repr(key) for key in absent)} (neither the frame nor the file's top level gives them)")
    fx, fy, cx, cy = (_number(where, key, merged[key]) for key in _INTRINSICS[:4])
    if fx <= 0 or fy <= 0:
        raise InputError(f"{where}: focal lengths fl_x, fl_y must be > 0, got {fx:g}, {fy:g}")
    size = tuple(_number(where, key, merged[key]) for key in ("w", "h"))
    if any(value <= 0 or not value.is_integer() for value in size):
        raise InputError(f"{where}: 'w' and 'h' must be positive whole numbers, got {merged['w']!r}, {merged['h']!r}")
    coefficients = {key: _number(where, key, merged[key]) if merged[key] is not None else 0.0 for key in _DISTORTION}
    fisheye = model == "OPENCV_FISHEYE"
    if fisheye:
        tangential = [f"{key} = {coefficients[key]:g}" for key in ("p1", "p2") if coefficients[key] != 0]
        if tangential:
            raise InputError(f"{where}: {', '.join(tangential)} is not supported with OPENCV_FISHEYE (OpenCV's fisheye model has k1 k2 k3 k4 only)")
        distortion = [coefficients[key] for key in ("k1", "k2", "k3", "k4")]
    elif coefficients["k4"] != 0:
        raise InputError(f"{where}: k4 = {coefficients['k4']:g} is not supported (OpenCV's pinhole distortion has k1 k2 p1 p2 k3 only)")
    else:
        distortion = [coefficients[key] for key in ("k1", "k2", "p1", "p2", "k3")]
        if distortion[4] == 0:
            distortion = distortion[:4]
    if not any(distortion):
        distortion = []
    K = np.array([[fx, 0.0, cx - PIXEL_CENTRE], [0.0, fy, cy - PIXEL_CENTRE], [0.0, 0.0, 1.0]])
    mask = _file(source, where, "mask_path", entry["mask_path"]) if entry.get("mask_path") is not None else None
    image = PosedImage(_file(source, where, "file_path", entry["file_path"]), mask, where)
    return _Frame(index, image, _camera_name(where, entry.get("camera")), _time(where, entry), K, (int(size[0]), int(size[1])),
                  np.array(distortion, dtype=np.float64), fisheye, rigid_pose(where, entry["transform_matrix"]))


def _camera_name(where: str, value: Any) -> str | None:
    """A frame's ``camera`` key as a name (None when absent)."""
    if value is None:
        return None
    if isinstance(value, int) and not isinstance(value, bool):
        return f"cam_{value:03d}"
    if isinstance(value, str) and value:
        return value
    raise InputError(f"{where}: 'camera' must be a non-empty string or a whole number, got {value!r}")


def _time(where: str, entry: Mapping[str, Any]) -> float | None:
    """A frame's ``time``, else its ``timestamp``, else None."""
    for key in ("time", "timestamp"):
        if entry.get(key) is not None:
            return _number(where, key, entry[key])
    return None


def _group_cameras(path: Path, frames: list[_Frame]) -> dict[str, list[_Frame]]:
    """The frames of each camera, by camera name, in order of first appearance."""
    named = [frame.camera is not None for frame in frames]
    if any(named) and not all(named):
        lacking = frames[named.index(False)]
        raise InputError(f"{lacking.where}: no 'camera' key, but other frames name their camera (give every frame one, or none)")
    groups: dict[Any, list[_Frame]] = {}
    for frame in frames:
        groups.setdefault(frame.camera if frame.camera is not None else frame.key(), []).append(frame)
    for group in groups.values():
        for frame in group[1:]:
            if frame.key() != group[0].key():
                raise InputError(f"{frame.where}: camera {frame.camera!r} has a different pose or intrinsics than in frames[{group[0].index}]; "
                                 "mmcsplat needs fixed cameras")
    if all(named):
        return {name: group for name, group in groups.items()}
    stems = [group[0].image.path.stem for group in groups.values()]
    if all(len(group) == 1 for group in groups.values()) and len(set(stems)) == len(stems):
        return dict(zip(stems, groups.values()))
    return {f"cam_{number:03d}": group for number, group in enumerate(groups.values())}


def _camera(name: str, frame: _Frame, scale: float) -> Camera:
    """The OpenCV camera of a frame, its translation in metres."""
    c2w_cv = frame.c2w @ GL_TO_CV
    R = c2w_cv[:3, :3].T
    try:
        return Camera(name=name, width=frame.size[0], height=frame.size[1], K=frame.K, R=R, t=-R @ (c2w_cv[:3, 3] * scale),
                      distortion=frame.distortion, fisheye=frame.fisheye)
    except ValueError as error:
        raise InputError(f"{frame.where}: {error}") from error


def _place_frames(path: Path, groups: dict[str, list[_Frame]], fps: float | None) -> tuple[dict[str, dict[int, PosedImage]], np.ndarray, float]:
    """Each camera's images by frame index, the seconds of the frame indices and the frame rate."""
    frames = [frame for group in groups.values() for frame in group]
    timed = [frame.time is not None for frame in frames]
    if any(timed) and not all(timed):
        lacking = frames[timed.index(False)]
        raise InputError(f"{lacking.where}: no 'time' or 'timestamp', but other frames have one (give every frame one, or none)")
    if all(timed):
        times = np.unique(np.round([frame.time for frame in frames], _DECIMALS))
        indices = {name: [int(np.searchsorted(times, round(frame.time, _DECIMALS))) for frame in group] for name, group in groups.items()}
        fps = 1.0 / float(np.median(np.diff(times))) if len(times) > 1 else stated_or_assumed(fps, 1, path)
    else:
        counts = {name: len(group) for name, group in groups.items()}
        if len(set(counts.values())) != 1:
            detail = ", ".join(f"{name}: {count}" for name, count in counts.items())
            raise InputError(f"{path}: cameras have different numbers of images ({detail}) and the frames carry no 'time': "
                             "add a time to every frame to say which images are simultaneous")
        groups = {name: sorted(group, key=lambda frame: natural_key(str(frame.image.path))) for name, group in groups.items()}
        indices = {name: list(range(len(group))) for name, group in groups.items()}
        count = next(iter(counts.values()))
        fps = stated_or_assumed(fps, count, path)
        times = np.arange(count, dtype=np.float64) / fps
    images: dict[str, dict[int, PosedImage]] = {}
    for name, group in groups.items():
        by_index = images[name] = {}
        for t, frame in zip(indices[name], group):
            if t in by_index:
                raise InputError(f"{frame.where}: camera {name!r} already has an image at time {times[t]:g} ({by_index[t].listed})")
            by_index[t] = frame.image
    return images, times, fps


def _heldout(path: Path, document: Mapping[str, Any], groups: dict[str, list[_Frame]]) -> list[str]:
    """The cameras whose images are all listed in ``val_filenames`` or ``test_filenames``."""
    listed: set[str] = set()
    for key in ("val_filenames", "test_filenames"):
        names = document.get(key, [])
        if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
            raise InputError(f"{path}: {key!r} must be a list of file paths")
        listed |= {os.path.normpath(path.parent / name) for name in names}
    heldout = []
    for name, group in groups.items():
        flags = [os.path.normpath(frame.image.path) in listed for frame in group]
        if all(flags):
            heldout.append(name)
        elif any(flags):
            raise InputError(f"{path}: camera {name!r} has images both held out (val/test_filenames) and not; hold out whole cameras")
    return heldout
