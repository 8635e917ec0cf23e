"""Read Qualisys Track Manager's calibration, ``*.qca.txt``: XML, one ``<camera>`` per camera.

Pose2Sim projects recorded with Qualisys cameras keep this file in ``calibration/``; reading it here spares
a conversion to TOML. Per camera (its name the ``serial`` attribute):

- ``<fov_video left top right bottom>``: the video's window on the sensor, in pixels, both ends
  included: the image is ``right - left + 1`` wide and ``bottom - top + 1`` high.
- ``<intrinsic>``: ``focalLengthU``/``V`` and ``centerPointU``/``V`` in 1/64 pixel of the whole sensor, so
  K's focal lengths are them over 64 and its principal point theirs over 64 less the window's corner;
  ``radialDistortion1``–``3`` and ``tangentalDistortion1``–``2`` are OpenCV's k1, k2, k3 and p1, p2 as
  they stand. (Pose2Sim's converter divides them by 64 too; on Pose2Sim's own demo the coefficients as they
  stand are what that capture's checkerboard calibration found, k1 −0.05 and k2 0.15 in its cam01 and cam02,
  and they fit the checkerboard images' corners closer than a 64th does, in 11 of 12 images.)
- ``<transform x y z r11 … r33>``: the camera's centre in millimetres and the world-to-camera rotation
  ``r`` (its rows the camera's axes in the world) of a camera looking down its −z with y up: in OpenCV's
  axes ``diag(1, −1, −1) · r``. Translations are therefore always millimetres, whatever ``--units`` says.

Cameras that film no video are left out, as Pose2Sim leaves them out: an inactive camera (``active="0"``)
and one whose ``model`` names neither video nor hybrid (a marker camera; Pose2Sim's own files write
``none``, kept). A camera whose view QTM rotates (``viewrotation`` not 0) or with a skew is refused naming
it: what either does to the exported video is not stated in the file.

This module only parses: :func:`mmcsplat.storage.calibration.read_calibration` dispatches here and
applies the choice of cameras and the rig's checks as for any calibration.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path
from typing import Any

import numpy as np

from mmcsplat.plugin_api.errors import InputError

#: The file names Qualisys Track Manager gives its calibrations.
QUALISYS_SUFFIXES = (".qca.txt", ".qca")
#: Qualisys's sensor coordinates are in 64ths of a pixel.
SUBPIXELS = 64.0
#: From a Qualisys camera's axes (looking down −z, y up) to OpenCV's (down +z, y down).
_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
_VIDEO_MODELS = ("video", "hybrid", "none")


def is_qualisys(path: Path) -> bool:
    """Whether ``path`` is named as Qualisys Track Manager names its calibrations."""
    return Path(path).name.lower().endswith(QUALISYS_SUFFIXES)


def qualisys_tables(path: Path) -> list[tuple[str, str, dict[str, Any]]]:
    """The video cameras of a ``.qca.txt`` as (name, where in the file, table in anipose's keys, translation
    in millimetres), in the file's order (module docstring)."""
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as error:
        raise InputError(f"calibration {path}: not a Qualisys calibration (not valid XML: {error})") from error
    cameras = root.findall(".//cameras/camera")
    if not cameras:
        raise InputError(f"calibration {path}: no <camera> elements (a Qualisys .qca.txt lists them under <cameras>)")
    tables = []
    for index, camera in enumerate(cameras, start=1):
        name = camera.get("serial") or f"camera {index}"
        where = f"camera {name!r} (the {_ordinal(index)} <camera>)"
        if camera.get("active", "1").strip() == "0" or not any(model in camera.get("model", "none").lower() for model in _VIDEO_MODELS):
            continue
        if _number(path, where, camera, "viewrotation", default=0.0) != 0:
            raise InputError(f"calibration {path}, {where}: viewrotation {camera.get('viewrotation')}: QTM turns this camera's view, and "
                             "what that does to its videos is not in the file; export with no rotation, or leave it out with --cameras")
        tables.append((name, where, _table(path, where, camera)))
    if not tables:
        raise InputError(f"calibration {path}: none of its {len(cameras)} cameras films video (all inactive or marker cameras)")
    return tables


def _table(path: Path, where: str, camera: ElementTree.Element) -> dict[str, Any]:
    fov, intrinsic, transform = (_element(path, where, camera, tag) for tag in ("fov_video", "intrinsic", "transform"))
    left, top, right, bottom = (_number(path, where, fov, key) for key in ("left", "top", "right", "bottom"))
    intrinsics = {key: _number(path, where, intrinsic, key) for key in ("focalLengthU", "focalLengthV", "centerPointU", "centerPointV")}
    if _number(path, where, intrinsic, "skew", default=0.0) != 0:
        raise InputError(f"calibration {path}, {where}: skew {intrinsic.get('skew')} is not read (its unit is not stated); a camera "
                         "with skew cannot be ingested from this file")
    coefficients = [_number(path, where, intrinsic, key, default=0.0) for key in
                    ("radialDistortion1", "radialDistortion2", "tangentalDistortion1", "tangentalDistortion2", "radialDistortion3")]
    axes = np.array([[_number(path, where, transform, f"r{row}{column}") for column in (1, 2, 3)] for row in (1, 2, 3)])
    centre = np.array([_number(path, where, transform, key) for key in ("x", "y", "z")])
    rotation = _TO_OPENCV @ axes
    K = [[intrinsics["focalLengthU"] / SUBPIXELS, 0.0, intrinsics["centerPointU"] / SUBPIXELS - left],
         [0.0, intrinsics["focalLengthV"] / SUBPIXELS, intrinsics["centerPointV"] / SUBPIXELS - top],
         [0.0, 0.0, 1.0]]
    return {"size": [right - left + 1, bottom - top + 1], "matrix": K, "distortions": coefficients,
            "rotation": rotation.tolist(), "translation": (-rotation @ centre).tolist()}


def _element(path: Path, where: str, camera: ElementTree.Element, tag: str) -> ElementTree.Element:
    element = camera.find(tag)
    if element is None:
        raise InputError(f"calibration {path}, {where}: no <{tag}>")
    return element


def _number(path: Path, where: str, element: ElementTree.Element, key: str, default: float | None = None) -> float:
    text = element.get(key)
    if text is None and default is not None:
        return default
    try:
        value = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"calibration {path}, {where}: <{element.tag}> {key} must be a number, got {text!r}") from None
    if not np.isfinite(value):
        raise InputError(f"calibration {path}, {where}: <{element.tag}> {key} is not finite")
    return value


def _ordinal(index: int) -> str:
    return f"{index}{'th' if 10 <= index % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(index % 10, 'th')}"
