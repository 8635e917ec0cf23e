"""The Dynamic3DGaussians / CMU Panoptic layout.

``train_meta.json`` and ``test_meta.json`` each hold ``w``, ``h`` and, per frame ``t`` and per camera slot
``c``, ``k[t][c]`` (3×3 intrinsics), ``w2c[t][c]`` (4×4 world-to-camera, OpenCV axes), ``fn[t][c]`` (an
image path relative to ``ims/``, e.g. ``"0/000000.jpg"``) and ``cam_id[t][c]``. Subject masks live at
``seg/{fn with .png}``; the test cameras usually have none. There is no distortion.

Cameras are named ``cam_NN`` after their ``cam_id``; the cameras of ``test_meta.json`` are marked held out.
The format stores a camera per frame, but mmcsplat's cameras are fixed: the same ``cam_id`` with a
different ``k`` or ``w2c`` at another frame is an error. Every file is checked at open, so a missing
image fails before anything is written. The format carries no frame rate: ``fps`` defaults to 30 (the
CMU Panoptic HD cameras').
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Reader, RecordedFrame, Recording
from mmcsplat.plugin_api.parameters import finite_positive, parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import metres_per_unit, read_calibration
from mmcsplat.storage.capture_files import read_image, read_json, read_mask, require_files

_KEYS = ("w", "h", "k", "w2c", "fn", "cam_id")
_SPLITS = ("train_meta.json", "test_meta.json")


@attrs.frozen
class _CameraFrames:
    """Where one camera's frames are: image and mask paths by frame index (masks may be absent)."""

    camera: Camera
    images: dict[int, Path]
    masks: dict[int, Path] | None
    meta: Path


@attrs.frozen
class D3DGSReader(Reader):
    """Reads the Dynamic3DGaussians layout; ``fps`` is the capture's frame rate, which the files lack."""

    fps: float = parameter(30.0, doc="the capture's frame rate, frames per second", converter=float, validator=finite_positive)

    def detect(self, source: Path) -> bool:
        """A folder with a ``train_meta.json``."""
        return (Path(source) / "train_meta.json").is_file()

    def open(self, source: Path, calibration: Path | None = None, units: str = "m") -> D3DGSRecording:
        """Parse both metas and check that every image (and mask, where a camera has any) exists.
        ``units`` is the unit of the translations of ``w2c`` (or of ``calibration``, which then replaces
        the cameras by name)."""
        source = Path(source)
        scale = metres_per_unit(units)
        cameras: dict[str, _CameraFrames] = {}
        heldout: list[str] = []
        num_frames = 0
        for split in _SPLITS:
            meta = source / split
            if split != "train_meta.json" and not meta.is_file():
                continue
            parsed, frames = _parse_meta(meta, source, scale)
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
        return D3DGSRecording(source, [cameras[name] for name in order], num_frames, self.fps, heldout)


def _parse_meta(meta: Path, source: Path, scale: float) -> tuple[dict[str, _CameraFrames], int]:
    """The cameras of one meta file (translations scaled to metres) and its number of frames."""
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
    cameras = {}
    for name, (K, pose, first) in poses.items():
        try:
            camera = Camera(name=name, width=width, height=height, K=K, R=pose[:3, :3], t=pose[:3, 3] * scale)
        except ValueError as error:
            raise InputError(f"{meta}: frame {first}: {error}") from error
        require_files(list(images[name].values()), f"image of camera {name} listed in {meta}:")
        cameras[name] = _CameraFrames(camera, images[name], _masks(source, name, images[name]), meta)
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


class D3DGSRecording(Recording):
    """An opened Dynamic3DGaussians capture; images are decoded on demand."""

    def __init__(self, source: Path, cameras: list[_CameraFrames], num_frames: int, fps: float, heldout: list[str]) -> None:
        self.source = source
        self._entries = {entry.camera.name: entry for entry in cameras}
        self.cameras = [entry.camera for entry in cameras]
        self.num_frames = num_frames
        self.fps = fps
        self.heldout = tuple(name for name in self._entries if name in heldout)
        self.has_masks = any(entry.masks is not None for entry in cameras)

    def _entry(self, camera: str) -> _CameraFrames:
        try:
            return self._entries[camera]
        except KeyError:
            raise KeyError(f"d3dgs source {self.source} has no camera {camera!r}") from None

    def present(self, camera: str) -> np.ndarray:
        """The frames listed for ``camera`` in its meta file."""
        present = np.zeros(self.num_frames, dtype=bool)
        present[list(self._entry(camera).images)] = True
        return present

    def frames(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        """Decode the listed frames of ``camera`` in ``indices``; sizes are checked against the meta's."""
        entry = self._entry(camera)
        for t in indices:
            path = entry.images.get(t)
            if path is None:
                continue
            rgb, _ = read_image(path)
            mask = read_mask(entry.masks[t]) if entry.masks is not None else None
            expected = (entry.camera.height, entry.camera.width)
            for what, array, file in (("image", rgb, path), ("mask", mask, entry.masks and entry.masks[t])):
                if array is not None and array.shape[:2] != expected:
                    raise InputError(f"{what} {file} is {array.shape[1]}×{array.shape[0]}, but {entry.meta} says "
                                     f"{expected[1]}×{expected[0]}")
            yield RecordedFrame(t=t, rgb=rgb, mask=mask)

    def describe(self) -> dict[str, Any]:
        """The format, the source and where the held-out cameras came from."""
        return {"format": "d3dgs", "source": str(self.source), "heldout_from": "test_meta.json", "fps_assumed": self.fps}
