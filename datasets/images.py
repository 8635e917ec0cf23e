"""The ``images`` format: one folder of images per calibrated camera plus an anipose or Pose2Sim calibration.

Layout: ``SOURCE/<camera>/*.{png,jpg,jpeg}`` or ``SOURCE/images/<camera>/…`` (the sub-folder wins when it
has camera folders), matched to the calibration's cameras by name (see :mod:`mmcsplat.datasets.rig`);
frame t of a camera is its t-th image in natural order (``frame2`` before ``frame10``). The calibration
is found as for the ``videos`` format. Images carry no frame rate: ``fps`` gives it (30 by default).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import attrs

from mmcsplat.datasets.rig import SIZE_MISMATCH_PARAMETER, RigRecording, common_length, find_calibration, fit_camera, match_cameras, natural_key
from mmcsplat.plugin_api.errors import NotAFolderError
from mmcsplat.plugin_api.interfaces import Reader, RecordedFrame, Recording
from mmcsplat.plugin_api.parameters import finite_positive, parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import read_calibration
from mmcsplat.storage.capture_files import PLATES_FOLDER, read_image

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def image_files(folder: Path) -> list[Path]:
    """The images in ``folder``, in natural order."""
    return sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES), key=lambda p: natural_key(p.name))


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

    fps: float = parameter(30.0, doc="the capture's frame rate", validator=finite_positive)
    size_mismatch: str = SIZE_MISMATCH_PARAMETER

    def detect(self, source: Path) -> bool:
        source = Path(source)
        return source.is_dir() and any(source.glob("*.toml")) and bool(camera_folders(source))

    def open(self, source: Path, calibration: Path | None = None, units: str = "m") -> Recording:
        source = Path(source)
        if not source.is_dir():
            raise NotAFolderError(f"images source {source} is not a folder")
        calibration = find_calibration(source, calibration)
        calibrated = read_calibration(calibration, units)
        folders = match_cameras(calibrated, camera_folders(source), "image folder", source)
        files = {name: image_files(folder) for name, folder in folders.items()}
        num_frames = common_length({name: len(paths) for name, paths in files.items()}, "image folder", source)
        cameras = []
        for camera in calibrated:
            first, _ = read_image(files[camera.name][0])
            cameras.append(fit_camera(camera, first.shape[1], first.shape[0], self.size_mismatch, f"image {files[camera.name][0]}"))
        provenance = {
            "calibration": str(calibration),
            "units": units,
            "folders": {name: str(folder) for name, folder in folders.items()},
            "size_mismatch": self.size_mismatch,
        }
        return ImageRecording(source, cameras, self.fps, num_frames, provenance, files)


class ImageRecording(RigRecording):
    """Per-camera image sequences, decoded on demand."""

    def __init__(self, source: Path, cameras: Sequence[Camera], fps: float, num_frames: int, provenance: dict, files: dict[str, list[Path]]) -> None:
        super().__init__(source, cameras, fps, num_frames, provenance)
        self._files = files

    def _decode(self, camera: str, indices: range) -> Iterator[RecordedFrame]:
        for t in indices:
            rgb, _ = read_image(self._files[camera][t])
            yield RecordedFrame(t=t, rgb=rgb)
