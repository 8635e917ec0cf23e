"""The Dynamic3DGaussians / CMU Panoptic layout.

``train_meta.json`` and ``test_meta.json`` each hold ``w``, ``h`` and, per frame ``t`` and per camera slot
``c``, ``k[t][c]`` (3×3 intrinsics), ``w2c[t][c]`` (4×4 world-to-camera, OpenCV axes), ``fn[t][c]`` (an
image path relative to ``ims/``, e.g. ``"0/000000.jpg"``) and ``cam_id[t][c]``. Subject masks live at
``seg/{fn with .png}``; the test cameras usually have none. There is no distortion.

Cameras are named ``cam_NN`` after their ``cam_id``; the cameras of ``test_meta.json`` are marked held out.
The format stores a camera per frame, but mmcsplat's cameras are fixed: the same ``cam_id`` with a
different ``k`` or ``w2c`` at another frame is an error. Every file is checked at open, so a missing
image fails before anything is written, the error listing every missing one; with
``missing_frames="absent"`` they are skipped (:mod:`mmcsplat.datasets.posed_images`). The format carries
no frame rate: ``fps`` defaults to 30 (the CMU Panoptic HD cameras').
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.datasets.posed_images import MISSING_FRAMES_PARAMETER, PosedImage, PosedImageRecording, missing_files
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Reader
from mmcsplat.plugin_api.parameters import finite_positive, parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import AUTO_UNITS, metres_per_unit, read_calibration
from mmcsplat.storage.capture_files import read_json, require_files

_KEYS = ("w", "h", "k", "w2c", "fn", "cam_id")
_SPLITS = ("train_meta.json", "test_meta.json")


@attrs.frozen
class _CameraFrames:
    """One camera and its images (with their masks, where it has any) by frame index."""

    camera: Camera
    images: dict[int, PosedImage]
    meta: Path


@attrs.frozen
class D3DGSReader(Reader):
    """Reads the Dynamic3DGaussians layout; ``fps`` is the capture's frame rate, which the files lack,
    ``missing_frames`` what a listed image that is not on disk does."""

    fps: float = parameter(30.0, doc="the capture's frame rate, frames per second", converter=float, validator=finite_positive)
    missing_frames: str = MISSING_FRAMES_PARAMETER

    def detect(self, source: Path) -> bool:
        """A folder with a ``train_meta.json``."""
        return (Path(source) / "train_meta.json").is_file()

    def open(self, source: Path, calibration: Path | None = None, units: str = AUTO_UNITS) -> PosedImageRecording:
        """Parse both metas and check that every image (and mask, where a camera has any) exists.
        ``units`` is the unit of the translations of ``w2c`` (or of ``calibration``, which then replaces
        the cameras by name; ``auto``: ``w2c``'s in metres, the calibration's as its rig decides)."""
        source = Path(source)
        scale = metres_per_unit(units)
        cameras: dict[str, _CameraFrames] = {}
        heldout: list[str] = []
        num_frames = 0
        for split in _SPLITS:
            meta = source / split
            if split != "train_meta.json" and not meta.is_file():
                continue
            parsed, frames = _parse_meta(meta, source, scale, self.missing_frames)
            num_frames = max(num_frames, frames)
            for name, entry in parsed.items():
                if name in cameras:
                    raise InputError(f"{meta}: camera {name} also appears in {cameras[name].meta}")
                cameras[name] = entry
                if split == "test_meta.json":
                    heldout.append(name)
        if calibration is not None:
            cameras = _override(cameras, Path(calibration), units)
        order = sorted(cameras, key=lambda name: (len(name), name))
        provenance = {"format": "d3dgs", "heldout_from": "test_meta.json", "fps_assumed": self.fps,
                      "masks": "seg/ beside ims/" if any(image.mask for entry in cameras.values() for image in entry.images.values()) else None}
        return PosedImageRecording(source, [cameras[name].camera for name in order], {name: cameras[name].images for name in order},
                                   np.arange(num_frames) / self.fps, self.fps, [name for name in order if name in heldout], provenance)


def _parse_meta(meta: Path, source: Path, scale: float, missing_frames: str) -> tuple[dict[str, _CameraFrames], int]:
    """The cameras of one meta file (translations scaled to metres; a camera whose images are all
    skipped as missing is left out) and its number of frames."""
    document = read_json(meta, _KEYS)
    try:
        width, height = int(document["w"]), int(document["h"])
    except (TypeError, ValueError):
        raise InputError(f"{meta}: 'w' and 'h' must be whole numbers, got {document['w']!r}, {document['h']!r}") from None
    lengths = {key: len(document[key]) if isinstance(document[key], list) else None for key in _KEYS[2:]}
    if None in lengths.values() or len(set(lengths.values())) != 1:
        raise InputError(f"{meta}: 'k', 'w2c', 'fn' and 'cam_id' must be lists with one entry per frame, got lengths {lengths}")
    poses: dict[str, tuple[np.ndarray, np.ndarray, int]] = {}
    images: dict[str, dict[int, Path]] = {}
    for t, (ks, w2cs, fns, ids) in enumerate(zip(*(document[key] for key in _KEYS[2:]))):
        if not all(isinstance(row, list) for row in (ks, w2cs, fns, ids)) or not len(ks) == len(w2cs) == len(fns) == len(ids):
            raise InputError(f"{meta}: frame {t}: 'k', 'w2c', 'fn' and 'cam_id' must be lists of one length")
        for slot, (k, w2c, fn, cam_id) in enumerate(zip(ks, w2cs, fns, ids)):
            where = f"{meta}: frame {t}, entry {slot}"
            name = _camera_name(where, cam_id)
            K, pose = _matrix(where, "k", k, (3, 3)), _matrix(where, "w2c", w2c, (4, 4))
            if name not in poses:
                poses[name] = (K, pose, t)
                images[name] = {}
            elif not (np.allclose(K, poses[name][0], rtol=1e-6, atol=1e-9) and np.allclose(pose, poses[name][1], rtol=1e-6, atol=1e-9)):
                raise InputError(f"{where}: camera {name} has a different k or w2c than at frame {poses[name][2]}; "
                                 "mmcsplat needs fixed cameras")
            if t in images[name]:
                raise InputError(f"{where}: camera {name} appears twice in frame {t}")
            if not isinstance(fn, str):
                raise InputError(f"{where}: 'fn' must be a file name, got {fn!r}")
            images[name][t] = source / "ims" / fn
    missing = missing_files([path for by_index in images.values() for path in by_index.values()], f"images listed in {meta}", missing_frames)
    cameras = {}
    for name, (K, pose, first) in poses.items():
        try:
            camera = Camera(name=name, width=width, height=height, K=K, R=pose[:3, :3], t=pose[:3, 3] * scale)
        except ValueError as error:
            raise InputError(f"{meta}: frame {first}: {error}") from error
        present = {t: path for t, path in images[name].items() if path not in missing}
        if present:
            masks = _masks(source, name, present)
            cameras[name] = _CameraFrames(camera, {t: PosedImage(path, masks[t] if masks else None, str(meta)) for t, path in present.items()}, meta)
    return cameras, len(document["fn"])


def _camera_name(where: str, cam_id: Any) -> str:
    """``cam_NN`` for a whole-number ``cam_id`` (an int, an integral float or a string of digits)."""
    whole = (isinstance(cam_id, int) and not isinstance(cam_id, bool)) or (isinstance(cam_id, float) and cam_id.is_integer())
    if not (whole or (isinstance(cam_id, str) and cam_id.isdigit())):
        raise InputError(f"{where}: 'cam_id' must be a whole number, got {cam_id!r}")
    return f"cam_{int(cam_id):02d}"


def _matrix(where: str, key: str, value: Any, shape: tuple[int, int]) -> np.ndarray:
    """``value`` as a finite float matrix of ``shape``, or an error naming ``key``."""
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key!r} must be a {shape[0]}×{shape[1]} matrix of numbers") from None
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise InputError(f"{where}: {key!r} must be a finite {shape[0]}×{shape[1]} matrix, got shape {array.shape}")
    return array


def _masks(source: Path, name: str, images: dict[int, Path]) -> dict[int, Path] | None:
    """The camera's mask paths, or None when it has none; a camera with some masks must have them all."""
    masks = {t: source / "seg" / path.relative_to(source / "ims").with_suffix(".png") for t, path in images.items()}
    present = [path.is_file() for path in masks.values()]
    if not any(present):
        return None
    require_files(list(masks.values()), f"mask of camera {name} (which has masks for other frames):")
    return masks


def _override(cameras: dict[str, _CameraFrames], calibration: Path, units: str) -> dict[str, _CameraFrames]:
    """Replace the cameras by the calibration's cameras of the same names."""
    replacements = {camera.name: camera for camera in read_calibration(calibration, units)}
    missing = sorted(set(cameras) - set(replacements))
    if missing:
        raise InputError(f"calibration {calibration} lacks camera(s) {', '.join(missing)} of the d3dgs source")
    return {name: attrs.evolve(entry, camera=replacements[name]) for name, entry in cameras.items()}
