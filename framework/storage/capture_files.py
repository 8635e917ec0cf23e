"""Reading the metadata and image files of dataset formats, with errors that name the file at fault."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError

#: Where ingest looks for clean plates when none are named: this folder of the capture (readers skip it).
PLATES_FOLDER = "plates"


def read_json(path: Path, required: tuple[str, ...] = ()) -> dict[str, Any]:
    """The JSON object in ``path``; a clear error when it is missing, malformed, or lacks a ``required`` key."""
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise MissingFileError(f"{path}: file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: not valid JSON: {error}") from error
    if not isinstance(document, Mapping):
        raise InputError(f"{path}: expected a JSON object at the top level, got {type(document).__name__}")
    missing = [key for key in required if key not in document]
    if missing:
        raise InputError(f"{path}: missing key(s) {', '.join(repr(key) for key in missing)}")
    return dict(document)


def require_files(paths: list[Path], what: str) -> None:
    """Raise ``FileNotFoundError`` naming the first of ``paths`` that is not a file (``what`` says what it is)."""
    for path in paths:
        if not path.is_file():
            raise MissingFileError(f"{what} {path} not found")


def read_image(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """An image file as (rgb [H, W, 3] uint8, alpha [H, W] uint8 or None); 16-bit files are reduced to
    8 bits and grey images expanded to RGB."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: not a readable image" if Path(path).is_file() else f"image {path} not found")
    image = _to_uint8(image, path)
    if image.ndim == 2:
        return np.repeat(image[:, :, None], 3, axis=2), None
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB), np.ascontiguousarray(image[:, :, 3])
    if image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB), None
    raise InputError(f"{path}: unsupported image with {image.shape[2]} channels")


def read_mask(path: Path) -> np.ndarray:
    """A mask image as [H, W] bool. Values above half the range are foreground; a mask stored as 0/1
    (a 1-bit PNG decoded without scaling, or an 8-bit 0/1 image) counts its ones."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: not a readable mask image" if Path(path).is_file() else f"mask {path} not found")
    image = _to_uint8(image, path)
    if image.ndim == 3:
        image = image[:, :, :3].max(axis=2)
    return image > (0 if image.max(initial=0) <= 1 else 127)


def _to_uint8(image: np.ndarray, path: Path) -> np.ndarray:
    """8-bit data from an 8- or 16-bit decoded image."""
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16:
        return np.round(image / 257.0).astype(np.uint8)
    raise InputError(f"{path}: unsupported pixel type {image.dtype} (expected 8- or 16-bit)")
