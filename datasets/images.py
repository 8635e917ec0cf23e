"""The ``images`` format: one folder of images per calibrated camera plus an anipose or Pose2Sim calibration,
or EasyMocap's ``intri.yml`` + ``extri.yml`` (ZJU-MoCap's layout: them beside ``images/<camera>/000000.jpg``).

Layout: ``SOURCE/<camera>/*.{png,jpg,jpeg}`` or ``SOURCE/images/<camera>/…`` (the sub-folder wins when it
has camera folders), matched to the calibration's cameras by name (see :mod:`mmcsplat.datasets.rig`);
frame t of a camera is its t-th image in natural order (``frame2`` before ``frame10``). The calibration
is found as for the ``videos`` format; a camera it states no image size for (EasyMocap's may not) takes
its first image's. Images carry no frame rate: ``fps`` gives it (30 by default, with a warning: :mod:`.frame_rate`).

Masks the capture brings: ``SOURCE/masks/<camera>/`` holds a mask image per frame with the frame image's
stem (``masks/cam_01/frame0012.png`` for ``cam_01/frame0012.jpg``; a missing one is an error listing
them); else an image's alpha channel (RGBA PNGs) is its mask (alpha > 127), its colour kept as stored.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.datasets.frame_rate import FPS_PARAMETER, stated_or_assumed
from mmcsplat.datasets.posed_images import ALPHA_THRESHOLD, MISSING_FRAMES_PARAMETER
from mmcsplat.datasets.rig import (
    CALIBRATION_FOLDERS,
    CAMERA_MAP_PARAMETER,
    CAMERAS_PARAMETER,
    MASKS_FOLDER,
    SIZE_MISMATCH_PARAMETER,
    RigRecording,
    calibration_candidates,
    common_length,
    find_calibration,
    fit_camera,
    mask_folders,
)
from mmcsplat.plugin_api.errors import InputError, MissingFileError, NotAFolderError
from mmcsplat.plugin_api.interfaces import Reader, RecordedFrame, Recording
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import AUTO_UNITS, calibration_names, read_rig
from mmcsplat.storage.camera_names import match_cameras, natural_key
from mmcsplat.storage.capture_files import PLATES_FOLDER, read_image

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def image_files(folder: Path) -> list[Path]:
    """The images in ``folder``, in natural order."""
    return sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES), key=lambda p: natural_key(p.name))


def frame_number(path: Path) -> int | None:
    """The frame number in an image's name: its last run of digits (``frame0012.png`` → 12)."""
    digits = re.findall(r"\d+", path.stem)
    return int(digits[-1]) if digits else None


def frames_by_number(files: dict[str, list[Path]], missing_frames: str,
                     source: Path) -> tuple[dict[str, list[Path | None]], int, int | None]:
    """Each camera's images placed at frame index = number − the first number of the capture, so that
    a missing file shifts nothing; a gap is an error, or with ``missing_frames="absent"`` a frame the
    camera lacks. Names without numbers (or repeated numbers) keep the sorted order, as before. Returns the
    placed files, the number of frames and that first number (``None`` for names without numbers)."""
    numbers = {name: [frame_number(path) for path in paths] for name, paths in files.items()}
    if any(None in found or len(set(found)) != len(found) for found in numbers.values()):
        length = common_length({name: len(paths) for name, paths in files.items()}, "image folder", source)
        return {name: list(paths[:length]) for name, paths in files.items()}, length, None
    first = min(min(found) for found in numbers.values())
    length = common_length({name: max(found) - first + 1 for name, found in numbers.items()}, "image folder", source)
    placed: dict[str, list[Path | None]] = {}
    gaps: dict[str, list[int]] = {}
    for name, paths in files.items():
        slots: list[Path | None] = [None] * length
        for number, path in zip(numbers[name], paths, strict=True):
            if number - first < length:
                slots[number - first] = path
        gaps[name] = [first + t for t, path in enumerate(slots) if path is None]
        placed[name] = slots
    listed = "; ".join(f"camera {name!r} has no image numbered {', '.join(map(str, absent))}" for name, absent in gaps.items() if absent)
    if listed and missing_frames == "error":
        raise InputError(f"{source}: {listed} (frames are matched by the number in their file names; pass --skip-missing to mmcsplat "
                         "ingest, the reader option missing_frames=absent, to ingest the rest with those frames absent)")
    if listed:
        warnings.warn(f"{source}: {sum(map(len, gaps.values()))} frames absent: {listed}", stacklevel=3)
    return placed, length, first


def camera_folders(source: Path) -> list[Path]:
    """The folders holding images: those in ``source/images`` if any, else those directly in ``source``
    (except the clean plates' folder, which ingest reads)."""
    for root in (source / "images", source):
        if root.is_dir():
            found = sorted(p for p in root.iterdir() if p.is_dir() and p.name != PLATES_FOLDER and image_files(p))
            if found:
                return found
    return []


@attrs.frozen
class ImageSequenceReader(Reader):
    """Reads per-camera image folders."""

    fps: float | None = FPS_PARAMETER
    size_mismatch: str = SIZE_MISMATCH_PARAMETER
    camera_map: Mapping[str, str] | str | None = CAMERA_MAP_PARAMETER
    cameras: tuple[str, ...] | None = CAMERAS_PARAMETER
    missing_frames: str = MISSING_FRAMES_PARAMETER

    def detect(self, source: Path) -> bool:
        source = Path(source)
        calibrated = any(calibration_candidates(source / name) for name in CALIBRATION_FOLDERS)
        return source.is_dir() and calibrated and bool(camera_folders(source))

    def open(self, source: Path, calibration: Path | None = None, units: str = AUTO_UNITS) -> Recording:
        source = Path(source)
        if not source.is_dir():
            raise NotAFolderError(f"images source {source} is not a folder")
        calibration = find_calibration(source, calibration)
        # Matched by name first: a calibration stating no image size takes its images' (read_rig's sizes).
        names = calibration_names(calibration, self.cameras)
        folders = match_cameras(names, camera_folders(source), "image folder", source, self.camera_map)
        files, num_frames, first_number = frames_by_number({name: image_files(folder) for name, folder in folders.items()}, self.missing_frames, source)
        firsts = {name: next(path for path in files[name] if path is not None) for name in names}
        sizes, alpha = {}, []
        for name, path in firsts.items():
            first, first_alpha = read_image(path)
            sizes[name] = (first.shape[1], first.shape[0])
            if first_alpha is not None:
                alpha.append(name)
        rig = read_rig(calibration, units, names, sizes)
        calibrated = rig.cameras
        cameras = [fit_camera(camera, *sizes[camera.name], self.size_mismatch, f"image {firsts[camera.name]}") for camera in calibrated]
        masks = _frame_masks(source, calibrated, files, self.camera_map)
        provenance = {
            "calibration": str(calibration),
            "units": rig.units,
            "folders": {name: str(folder) for name, folder in folders.items()},
            # Frame index t is the image numbered first_number + t (what OpenPose names an image's keypoints by).
            "first_number": first_number,
            "size_mismatch": self.size_mismatch,
            "masks": f"{source / MASKS_FOLDER}" if masks else "the images' alpha channel (alpha > 127)" if alpha else None,
        }
        return ImageRecording(source, cameras, stated_or_assumed(self.fps, num_frames, source), num_frames, provenance, files, masks, () if masks else alpha)


def _frame_masks(source: Path, cameras: Sequence[Camera], files: dict[str, list[Path | None]],
                 camera_map: Mapping[str, str] | str | None) -> dict[str, list[Path | None]]:
    """Each camera's mask per frame from ``SOURCE/masks/<camera>/``, by the frame image's stem; empty without
    that folder. Every present frame needs its mask."""
    folders = mask_folders(source, cameras, camera_map)
    masks: dict[str, list[Path | None]] = {}
    lacking = []
    for name, paths in folders.items():
        by_stem = {path.stem: path for path in paths}
        masks[name] = [None if image is None else by_stem.get(image.stem) for image in files[name]]
        lacking += [f"{name}/{image.stem}" for image, mask in zip(files[name], masks[name]) if image is not None and mask is None]
    if lacking:
        raise MissingFileError(f"{source / MASKS_FOLDER}: no mask for {len(lacking)} frame(s): {', '.join(lacking)} (each frame's mask has "
                               "its image's name)")
    return masks


class ImageRecording(RigRecording):
    """Per-camera image sequences, decoded on demand; the cameras in ``alpha`` take their masks from the
    images' alpha channel."""

    def __init__(self, source: Path, cameras: Sequence[Camera], fps: float, num_frames: int, provenance: dict,
                 files: dict[str, list[Path | None]], masks: dict[str, list[Path | None]] | None = None, alpha: Sequence[str] = ()) -> None:
        super().__init__(source, cameras, fps, num_frames, provenance, masks)
        self._files = files
        self._alpha = frozenset(alpha)
        self.has_masks = self.has_masks or bool(self._alpha)

    def present(self, camera: str) -> np.ndarray:
        """The frames whose image exists (all, unless ingested with ``missing_frames="absent"``)."""
        return np.array([path is not None for path in self._files[camera]], dtype=bool)

    def source_frames(self, camera: str) -> np.ndarray:
        """Each frame's position among this camera's images (−1 where it lacks the frame): what a detector
        that runs through the folder numbers its output by (Pose2Sim's JSON, SLEAP's and DeepLabCut's rows)."""
        present = self.present(camera)
        return np.where(present, np.cumsum(present) - 1, -1)

    def _decode(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        for t in indices:
            path = self._files[camera][t]
            if path is not None:
                rgb, alpha = read_image(path)
                mask = alpha > ALPHA_THRESHOLD if camera in self._alpha and alpha is not None else None
                yield RecordedFrame(t=t, rgb=rgb, mask=mask)
