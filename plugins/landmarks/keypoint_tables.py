"""What the keypoint sources that read one table per camera (``deeplabcut``, ``sleap``) share: the files
of a folder matched to the session's cameras, each read as (names, frame numbers, [T, L, 3] table of x, y,
confidence in the recorded video's pixels), and turned into observations in the stored images' pixels.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.plugin_api.parameters import between, parameter
from mmcsplat.storage.camera_names import match_cameras
from mmcsplat.storage.session import SessionReader

from .triangulation import TriangulatedKeypoints, recorded_cameras, to_session_pixels

#: One camera's keypoints: (names, frame numbers [T], [T, L, 3] x, y, confidence; NaN where undetected).
KeypointTable = tuple[tuple[str, ...], np.ndarray, np.ndarray]


@attrs.frozen
class TableKeypoints(TriangulatedKeypoints):
    """Keypoints read from one file per camera in ``folder``, triangulated; subclasses say which files and
    how to read one."""

    folder: str = parameter(doc="the folder of one keypoint file per camera", kw_only=True)
    min_confidence: float = parameter(0.6, doc="detections of lower confidence are not used", validator=between(0, 1))
    camera_map: dict | None = parameter(None, doc="session camera name → its file's name (without the suffix), where the names differ")

    @abstractmethod
    def files(self, folder: Path) -> dict[str, Path]:
        """The keypoint files of ``folder`` by the name they are matched to cameras with."""

    @abstractmethod
    def read_table(self, path: Path) -> KeypointTable:
        """One camera's keypoints."""

    def observations(self, session: SessionReader, frames: Sequence[int]) -> list[KeypointObservations]:
        """Every camera's detections at ``frames``, in the stored images' pixels."""
        folder = Path(self.folder)
        if not folder.is_dir():
            raise MissingFileError(f"{self.described}: folder {folder} does not exist")
        cameras = [session.camera(name) for name in session.camera_names]
        # Matched by name: the file's own path when its stem is the name, else a stand-in path named after it.
        files = {folder / label: path for label, path in self.files(folder).items()}
        matched = {name: files[path] for name, path in match_cameras(cameras, list(files), "keypoint file", folder, self.camera_map).items()}
        recorded = recorded_cameras(session)
        capture = session.capture_frames(frames)
        result, names = [], None
        for camera in cameras:
            parts, numbers, table = self.read_table(matched[camera.name])
            if names is not None and parts != names:
                raise InputError(f"{matched[camera.name]}: keypoint names {list(parts)} differ from the other cameras' {list(names)}")
            names = parts
            rows = {int(number): k for k, number in enumerate(numbers)}
            pixels = np.zeros((len(frames), len(parts), 2))
            confidence = np.zeros((len(frames), len(parts)))
            for k, number in enumerate(capture):
                if int(number) in rows:
                    found = table[rows[int(number)]]
                    known = np.all(np.isfinite(found), axis=1)
                    pixels[k, known], confidence[k, known] = found[known, :2], found[known, 2]
            if camera.name in recorded:
                pixels = to_session_pixels(pixels, recorded[camera.name], camera)
            confidence[confidence < self.min_confidence] = 0.0
            result.append(KeypointObservations(camera.name, parts, frames, pixels, confidence))
        return result
