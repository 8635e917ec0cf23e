"""Read OpenCap's calibration: one ``cameraIntrinsicsExtrinsics.pickle`` in each camera's folder.

OpenCap (smartphone markerless motion capture) keeps each phone's calibration in
``Videos/CamN/cameraIntrinsicsExtrinsics.pickle`` of a session (the web app's download, or a session
processed by opencap-core): a pickled dict of numpy arrays, ``intrinsicMat`` (3×3 K), ``distortion``
(1×5: OpenCV's k1 k2 p1 p2 k3), ``imageSize`` (2×1: height, width of the upright frames the phone
recorded), ``rotation`` (3×3, world to camera: x_cam = R X + t) and ``translation`` (3×1, millimetres),
in the frame of the checkerboard the session was calibrated on (origin at its first inner corner, z
through the board). The camera is named after its folder (``Cam0``, ``Cam1``, …, in number order).

One pickle stands for the rig: its siblings (the other camera folders beside its own holding the same
file) are the other cameras, as one file of EasyMocap's pair stands for both. The pickles are read by
:func:`mmcsplat.storage.plain_pickle.load_plain`, which builds numpy arrays and nothing else: a pickle
can run code, and a calibration is a file from elsewhere.

This module only parses: :func:`mmcsplat.storage.calibration.read_calibration` dispatches here and
applies the units (always millimetres), the choice of cameras and the rig's checks as for any calibration.
"""

from __future__ import annotations

import pickle
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.camera_names import natural_key
from mmcsplat.storage.landmark_formats import TRC_AXES
from mmcsplat.storage.plain_pickle import load_plain

#: The name of a camera's calibration file in its folder.
OPENCAP_CALIBRATION = "cameraIntrinsicsExtrinsics.pickle"
#: OpenCap's TRC conventions (:data:`~.landmark_formats.TRC_AXES`), one per placement of the board.
TRC_PLACEMENTS = ("opencap-ground", "opencap-wall", "opencap-wall-inverted")
#: The least cosine between the phones' mean image "up" and the board's axis a placement takes for up.
UPRIGHT_COSINE = 0.7
#: The keys read, and each one's shape.
SHAPES = {"intrinsicMat": (3, 3), "distortion": (5,), "imageSize": (2,), "rotation": (3, 3), "translation": (3,)}


def is_opencap(path: Path) -> bool:
    """Whether ``path`` names an OpenCap camera's calibration file."""
    return Path(path).name == OPENCAP_CALIBRATION


def opencap_files(folder: Path) -> list[Path]:
    """The calibration files of the camera folders directly in ``folder``, in the cameras' number order."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted((path for path in folder.glob(f"*/{OPENCAP_CALIBRATION}") if path.is_file()), key=lambda path: natural_key(path.parent.name))


def opencap_tables(path: Path) -> list[tuple[str, str, dict[str, Any]]]:
    """The rig that ``path`` (one camera's file) belongs to, as calibration tables (name, where, table):
    ``size`` [width, height], ``matrix``, ``distortions``, ``rotation`` (3×3) and ``translation`` (mm)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"calibration {path} does not exist")
    rig = path.parent.parent
    return [(file.parent.name, str(file.relative_to(rig)), _table(file)) for file in opencap_files(rig)]


def _table(path: Path) -> dict[str, Any]:
    """One camera's table from its pickle; errors name the file and the key at fault."""
    try:
        content = load_plain(path.read_bytes(), arrays=True)
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, IndexError) as error:
        raise InputError(f"calibration {path}: not OpenCap's pickle of arrays ({error})") from None
    if not isinstance(content, dict):
        raise InputError(f"calibration {path}: holds a {type(content).__name__}, not OpenCap's dict of arrays")
    missing = [key for key in SHAPES if key not in content]
    if missing:
        raise InputError(f"calibration {path}: missing {', '.join(missing)} (OpenCap's keys: {', '.join(SHAPES)})")
    values = {}
    for key, shape in SHAPES.items():
        try:
            value = np.asarray(content[key], dtype=np.float64).reshape(shape)
        except (TypeError, ValueError):
            size = np.size(content[key])
            raise InputError(f"calibration {path}: {key} must hold {int(np.prod(shape))} numbers, got {size}") from None
        if not np.all(np.isfinite(value)):
            raise InputError(f"calibration {path}: {key} is not finite")
        values[key] = value
    height, width = values["imageSize"]
    return {"size": [width, height], "matrix": values["intrinsicMat"], "distortions": values["distortion"],
            "rotation": values["rotation"], "translation": values["translation"]}


def opencap_convention(cameras: Sequence[Camera], where: str) -> str:
    """The TRC convention of OpenCap's markers for a session calibrated as ``cameras`` (board frame): the
    board's placement whose up (the TRC's Y) the phones' mean image up (−y) points along. OpenCap decides
    the same from its session's settings; the download keeps the markers, not the setting. An error naming
    ``where`` when no placement is within :data:`UPRIGHT_COSINE` (phones held at odd angles)."""
    up = -np.mean([camera.R[1] for camera in cameras], axis=0)  # image rows grow downwards
    up /= np.linalg.norm(up)
    cosines = {name: float(TRC_AXES[name][:, 1] @ up) for name in TRC_PLACEMENTS}
    best = max(cosines, key=cosines.get)
    if cosines[best] < UPRIGHT_COSINE:
        raise InputError(f"{where}: the cameras' image up is along no axis of the calibration board (best {best}, cosine "
                         f"{cosines[best]:.2f}): give the TRC's convention ({', '.join(TRC_PLACEMENTS)})")
    return best
