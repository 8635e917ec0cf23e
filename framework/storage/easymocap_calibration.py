"""Read EasyMocap's calibration: ``intri.yml`` and ``extri.yml``, OpenCV FileStorage YAML side by side.

EasyMocap, and the ZJU-MoCap captures made with it, keep these two files at the capture's root (beside
``images/<camera>/`` or ``videos/<camera>.mp4``); reading them here spares a conversion to TOML, whose
converters guess the image size as twice the principal point.

``intri.yml``: ``names`` (the cameras, a sequence of strings; a number stands for its digits), and per
camera ``K_<name>`` (3×3) and ``dist_<name>`` (k1 k2 p1 p2 [k3], any shape; older files call it
``D_<name>``), plus the image's ``H_<name>`` and ``W_<name>`` where EasyMocap knew them (it writes them
only then). ``extri.yml``: per camera ``Rot_<name>`` (3×3) and/or ``R_<name>`` (its Rodrigues vector),
and ``T_<name>`` (3×1): world to camera, x_cam = Rot X + T, T in metres; its ``names``, when present,
must list the same cameras. Matrices are OpenCV's ``!!opencv-matrix`` nodes. The files have no fisheye
flag: every camera is a pinhole with OpenCV's distortion.

This module only parses: :func:`mmcsplat.storage.calibration.read_calibration` dispatches here and
applies units, the choice of cameras and the rig's checks as for any calibration.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.scene.camera import Camera

if TYPE_CHECKING:  # cv2 is imported where used: importing the calibration readers stays quick
    import cv2

INTRINSICS = "intri.yml"
EXTRINSICS = "extri.yml"
#: The most Rot_ and R_ of one camera may disagree, radians (EasyMocap writes 6 decimals).
ROTATION_TOLERANCE = 1e-4


def easymocap_files(path: Path) -> tuple[Path, Path] | None:
    """``(intri.yml, extri.yml)`` when ``path`` names EasyMocap's calibration (either file, the other
    beside it, or their folder), else None. Neither file need exist."""
    path = Path(path)
    if path.name in (INTRINSICS, EXTRINSICS):
        return path.parent / INTRINSICS, path.parent / EXTRINSICS
    if path.is_dir():
        return path / INTRINSICS, path / EXTRINSICS
    return None


def easymocap_names(intri: Path) -> list[str]:
    """The camera names ``intri.yml`` lists, in its order."""
    return _names(_open(intri), intri, required=True)


def read_easymocap(intri: Path, extri: Path, names: Sequence[str], sizes: Mapping[str, tuple[int, int]] | None = None) -> list[Camera]:
    """The cameras ``names`` of the pair, in the files' units and unchecked (read_calibration checks them).

    A camera whose ``intri.yml`` states no image size takes ``sizes[name]`` (width, height), the size of
    its decoded images; with neither it is an error, never a guess.
    """
    intrinsics, extrinsics = _open(intri), _open(extri)
    own, listed = _names(intrinsics, intri, required=True), _names(extrinsics, extri, required=False)
    if listed is not None and set(listed) != set(own):
        only = [f"{', '.join(map(repr, sorted(set(first) - set(second))))} only in {path.name}"
                for first, second, path in ((listed, own, extri), (own, listed, intri)) if set(first) - set(second)]
        raise InputError(f"calibration {extri}: its names differ from {intri.name}'s: cameras {'; '.join(only)}")
    return [_camera(intri, intrinsics, extri, extrinsics, name, sizes or {}) for name in names]


def _open(path: Path) -> cv2.FileStorage:
    """``path`` opened for reading; errors say why it cannot be."""
    import cv2

    if not path.is_file():
        raise MissingFileError(f"calibration {path} does not exist (EasyMocap keeps {INTRINSICS} and {EXTRINSICS} side by side)")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as error:  # the binding raises a SystemError caused by the parser's cv2.error
        cause = str(error.__cause__ or error)
        found = re.search(r"\((\d+)\): ([^']*)'", cause)
        detail = f"line {found[1]}: {found[2]}" if found else cause.strip().splitlines()[-1]
        raise InputError(f"calibration {path}: not valid OpenCV YAML ({detail})") from None
    if not storage.isOpened():
        raise InputError(f"calibration {path}: not an OpenCV YAML file (EasyMocap's begin with %YAML:1.0)")
    return storage


def _names(storage: cv2.FileStorage, path: Path, required: bool) -> list[str] | None:
    """The ``names`` sequence as strings (a number as its digits, as EasyMocap reads it); None when the
    file has none and none is ``required``."""
    node = storage.getNode("names")
    if node.empty():
        if required:
            raise InputError(f"calibration {path}: missing names (the list of its cameras)")
        return None
    if not node.isSeq() or node.size() == 0:
        raise InputError(f"calibration {path}: names must be a non-empty sequence of camera names")
    names = []
    for index in range(node.size()):
        item = node.at(index)
        if item.isString():
            names.append(item.string())
        elif item.isInt():
            names.append(str(int(item.real())))
        else:
            raise InputError(f"calibration {path}: names[{index}] must be a camera name (a string)")
    return names


def _camera(intri: Path, intrinsics: cv2.FileStorage, extri: Path, extrinsics: cv2.FileStorage, name: str,
            sizes: Mapping[str, tuple[int, int]]) -> Camera:
    """One camera, every error naming its file and the camera."""
    where = f"calibration {intri}: camera {name!r}"
    K = _matrix(intrinsics, f"K_{name}", where, (3, 3))
    distortion = _distortion(intrinsics, name, where)
    size = _size(intrinsics, name, where)
    if size is None:
        if name not in sizes:
            raise InputError(f"{where}: no image size (H_{name}, W_{name}) and no images to take it from; add them to {intri.name}, "
                             "or read the calibration with its videos or images (mmcsplat ingest)")
        size = sizes[name]
    where = f"calibration {extri}: camera {name!r}"
    R = _rotation(extrinsics, name, where)
    t = _matrix(extrinsics, f"T_{name}", where, None).reshape(-1)
    if t.size != 3:
        raise InputError(f"{where}: T_{name} must hold 3 values, got {t.size}")
    try:
        return Camera(name=name, width=size[0], height=size[1], K=K, R=R, t=t, distortion=distortion)
    except ValueError as error:  # the Camera's own checks name the camera: add the files
        raise InputError(f"calibration {intri} and {extri.name}: {error}") from error


def _matrix(storage: cv2.FileStorage, key: str, where: str, shape: tuple[int, int] | None, required: bool = True) -> np.ndarray | None:
    """The ``!!opencv-matrix`` at ``key`` as finite float64 of ``shape`` (any when None); None when absent
    and not ``required``."""
    import cv2

    node = storage.getNode(key)
    if node.empty():
        if required:
            raise InputError(f"{where}: missing {key}")
        return None
    try:
        matrix = node.mat()
    except cv2.error:  # not a matrix node, or its data disagree with its rows and cols
        matrix = None
    if matrix is None:
        raise InputError(f"{where}: {key} must be an OpenCV matrix (!!opencv-matrix with rows, cols, dt, data)")
    matrix = np.asarray(matrix, dtype=np.float64)
    if shape is not None and matrix.shape != shape:
        raise InputError(f"{where}: {key} must be {shape[0]}×{shape[1]}, got {matrix.shape[0]}×{matrix.shape[1]}")
    if not np.all(np.isfinite(matrix)):
        raise InputError(f"{where}: {key} is not finite")
    return matrix


def _distortion(storage: cv2.FileStorage, name: str, where: str) -> np.ndarray:
    """k1 k2 p1 p2 [k3]: OpenCV's longer models are read when their further coefficients are zero."""
    key = f"dist_{name}"
    if storage.getNode(key).empty() and not storage.getNode(f"D_{name}").empty():
        key = f"D_{name}"  # older EasyMocap files' name
    values = _matrix(storage, key, where, None).reshape(-1)
    if values.size < 4:
        raise InputError(f"{where}: {key} must hold 4 (k1 k2 p1 p2) or 5 (… k3) values, got {values.size}")
    if np.any(values[5:] != 0):
        raise InputError(f"{where}: {key} holds {values.size} coefficients; only k1 k2 p1 p2 k3 are read, the rest must be 0")
    return values[:5]


def _size(storage: cv2.FileStorage, name: str, where: str) -> tuple[int, int] | None:
    """(width, height) from W_ and H_, or None when the file states neither."""
    nodes = {key: storage.getNode(f"{key}_{name}") for key in ("W", "H")}
    present = [key for key, node in nodes.items() if not node.empty()]
    if not present:
        return None
    if len(present) == 1:
        raise InputError(f"{where}: {present[0]}_{name} without {'H' if present[0] == 'W' else 'W'}_{name}")
    values = [node.real() if node.isInt() or node.isReal() else np.nan for node in nodes.values()]
    if not all(value > 0 and float(value).is_integer() for value in values):
        raise InputError(f"{where}: W_{name} and H_{name} must be positive whole numbers of pixels")
    return int(values[0]), int(values[1])


def _rotation(storage: cv2.FileStorage, name: str, where: str) -> np.ndarray:
    """Rot_ (preferred), else R_'s Rodrigues vector; both present must agree."""
    import cv2

    matrix = _matrix(storage, f"Rot_{name}", where, (3, 3), required=False)
    vector = _matrix(storage, f"R_{name}", where, None, required=False)
    if matrix is None and vector is None:
        raise InputError(f"{where}: missing Rot_{name} (or its Rodrigues vector R_{name})")
    if vector is not None and vector.size != 3:
        raise InputError(f"{where}: R_{name} must be a Rodrigues vector of 3 values, got {vector.size}")
    from_vector = None if vector is None else cv2.Rodrigues(vector.reshape(3, 1))[0]
    if matrix is None:
        return from_vector
    if np.abs(matrix.T @ matrix - np.eye(3)).max() > ROTATION_TOLERANCE:
        raise InputError(f"{where}: Rot_{name} is not a rotation matrix (its columns are not orthonormal)")
    if from_vector is not None:
        angle = float(np.linalg.norm(cv2.Rodrigues(matrix.T @ from_vector)[0]))
        if angle > ROTATION_TOLERANCE:
            raise InputError(f"{where}: Rot_{name} and R_{name} disagree by {np.degrees(angle):.3g}°; correct or delete one of them")
    return matrix
