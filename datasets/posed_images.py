"""What the readers of posed-image layouts (``nerfstudio``, ``colmap``, ``dnerf``, ``d3dgs``) share: the
recording of image files placed at frame indices, and one policy for listed images that are not on disk.

Missing images: by default an error that lists every missing file (a real ``transforms.json`` may lack a
quarter of its images; naming only the first sends the user back and forth). With the reader option
``missing_frames="absent"`` (``mmcsplat ingest --skip-missing``) they are skipped with one warning that
counts them: the camera lacks those frames, and a camera left with no image is left out.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import RecordedFrame, Recording
from mmcsplat.plugin_api.parameters import one_of, parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.capture_files import read_image, read_mask

#: What a reader does with an image its files list but the disk lacks (see the module's documentation).
MISSING_FRAMES_POLICIES = ("error", "absent")
#: The ``missing_frames`` parameter of the readers that list image files.
MISSING_FRAMES_PARAMETER = parameter("error", doc="a listed image not on disk: error (listing every one), or absent (skipped and counted)",
                                     validator=one_of(*MISSING_FRAMES_POLICIES))
#: Alpha above this (of 255) is the subject where an image's alpha channel is its mask.
ALPHA_THRESHOLD = 127


def missing_files(paths: Sequence[Path], what: str, policy: str) -> set[Path]:
    """The ``paths`` not on disk: with ``policy="error"`` an error listing every one, with ``"absent"`` a
    warning counting them (the caller leaves them out). ``what`` says what the paths are, e.g. "images
    listed in transforms.json"."""
    missing = [path for path in dict.fromkeys(paths) if not Path(path).is_file()]
    if not missing:
        return set()
    listed = ", ".join(str(path) for path in missing)
    if policy == "error":
        raise MissingFileError(f"{what}: {len(missing)} of {len(set(paths))} not found: {listed} (pass --skip-missing to mmcsplat ingest, "
                               "the reader option missing_frames=absent, to ingest the others with these frames absent)")
    warnings.warn(f"{what}: skipped {len(missing)} of {len(set(paths))} not found: {listed}", stacklevel=3)
    return set(missing)


def finite_matrix(where: str, key: str, value: Any, described: str) -> np.ndarray:
    """``value`` (the entry ``key``) as a finite float64 3×4 or 4×4 matrix, or an error naming ``where`` and
    ``key`` and calling the matrix ``described`` (its usual shape, "4×4" or "3×4")."""
    try:
        matrix = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key!r} must be a {described} matrix of numbers") from None
    if matrix.shape not in ((4, 4), (3, 4)) or not np.all(np.isfinite(matrix)):
        raise InputError(f"{where}: {key!r} must be a finite {described} matrix, got shape {matrix.shape}")
    return matrix


def rigid_pose(where: str, value: Any) -> np.ndarray:
    """A rigid 4×4 camera-to-world ``transform_matrix`` (a 3×4 one is completed), as D-NeRF's and nerfstudio's
    transforms.json give it; ``where`` names the frame in errors."""
    matrix = finite_matrix(where, "transform_matrix", value, "4×4")
    rotation = matrix[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-5) or np.linalg.det(rotation) < 0:
        raise InputError(f"{where}: 'transform_matrix' is not a rigid transform (its 3×3 part is not a rotation)")
    return np.vstack([matrix[:3], [0.0, 0.0, 0.0, 1.0]])


@attrs.frozen
class PosedImage:
    """One image of a camera: its file, its mask file (if any) and where it was listed (for errors)."""

    path: Path
    mask: Path | None
    listed: str


class PosedImageRecording(Recording):
    """Posed images placed at frame indices, decoded on demand: ``images[camera][t]`` is camera's image at
    frame index ``t`` (absent where missing); ``times`` are the frame indices' seconds. With
    ``alpha_mask`` an image's alpha channel is its mask and its colour is composited over black (the
    image a black-background render of the subject gives), where it has no mask file."""

    def __init__(self, source: Path, cameras: Sequence[Camera], images: Mapping[str, Mapping[int, PosedImage]], times: np.ndarray,
                 fps: float, heldout: Sequence[str] = (), provenance: Mapping[str, Any] | None = None, alpha_mask: bool = False) -> None:
        self.source = source
        self.cameras = list(cameras)
        self.heldout = tuple(heldout)
        self.num_frames = len(times)
        self.fps = float(fps)
        self.has_masks = alpha_mask or any(image.mask is not None for by_index in images.values() for image in by_index.values())
        self._alpha_mask = alpha_mask
        self._times = np.asarray(times, dtype=np.float64)
        self._images = {name: dict(by_index) for name, by_index in images.items()}
        self._cameras = {camera.name: camera for camera in self.cameras}
        self._provenance = dict(provenance or {})

    def _camera_images(self, camera: str) -> dict[int, PosedImage]:
        try:
            return self._images[camera]
        except KeyError:
            raise KeyError(f"source {self.source} has no camera {camera!r}") from None

    def present(self, camera: str) -> np.ndarray:
        """True at the frame indices where ``camera`` has an image."""
        present = np.zeros(self.num_frames, dtype=bool)
        present[list(self._camera_images(camera))] = True
        return present

    def frame_times(self) -> np.ndarray:
        """The seconds of each frame index."""
        return self._times.copy()

    def frames(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        """Decode ``camera``'s images (and masks) at ``indices``; their size is checked against the camera's."""
        by_index = self._camera_images(camera)
        expected = (self._cameras[camera].height, self._cameras[camera].width)
        for t in indices:
            image = by_index.get(t)
            if image is None:
                continue
            rgb, alpha = read_image(image.path)
            mask = read_mask(image.mask) if image.mask is not None else None
            for what, array, file in (("image", rgb, image.path), ("mask", mask, image.mask)):
                if array is not None and array.shape[:2] != expected:
                    raise InputError(f"{what} {file} is {array.shape[1]}×{array.shape[0]}, but {image.listed} gives camera "
                                     f"{camera!r} {expected[1]}×{expected[0]}")
            if self._alpha_mask and mask is None and alpha is not None:
                mask = alpha > ALPHA_THRESHOLD
                rgb = np.round(rgb * (alpha[:, :, None] / 255.0)).astype(np.uint8)
            yield RecordedFrame(t=t, rgb=rgb, mask=mask)

    def describe(self) -> dict[str, Any]:
        """The source and the conventions applied (see the reader's module)."""
        return {"source": str(self.source), **self._provenance}
