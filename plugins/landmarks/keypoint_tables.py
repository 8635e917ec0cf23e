"""What the keypoint sources that read one table per camera (``deeplabcut``, ``sleap``) share: the files
of a folder (or the files named) matched to the session's cameras, each read as (names, frame numbers,
[T, P, L, 3] table of x, y, confidence of P animals or people in the recorded video's pixels) and the
skeleton edges it declares, and turned into the subject's observations in the stored images' pixels.

Several animals in a file (DeepLabCut's multi-animal individuals, SLEAP's tracks): their identities are each
camera's own (a tracker's ``individual1`` in one camera need not be the same animal in another), so the
subject is chosen across cameras as for OpenPose's people (:mod:`.subject`), not by the identity's name.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from pathlib import Path
from typing import ClassVar

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.plugin_api.parameters import between, parameter
from mmcsplat.storage.camera_names import KEYPOINTS_CAMERA_MAP, match_cameras
from mmcsplat.storage.session import SessionReader

from .subject import SUBJECT_DOC, subject_observations
from .triangulation import TriangulatedKeypoints, detected_people, people_to_session_pixels

#: One camera's keypoints: (names, frame numbers [T], [T, P, L, 3] x, y, confidence of P animals or people;
#: NaN where undetected).
KeypointTable = tuple[tuple[str, ...], np.ndarray, np.ndarray]


@attrs.frozen
class TableKeypoints(TriangulatedKeypoints):
    """Keypoints read from one file per camera, in ``folder`` or named by ``files``, triangulated; subclasses
    say which file suffixes they read and how to read one."""

    folder: str | None = parameter(None, doc="the folder of one keypoint file per camera")
    files: tuple[str, ...] | None = parameter(None, doc="the keypoint files themselves, one per camera (instead of folder)")
    min_confidence: float = parameter(0.6, doc="detections of lower confidence are not used", validator=between(0, 1))
    camera_map: dict | str | None = parameter(None, doc="session camera name → its file's name (without the suffix), where the names "
                                               "differ; or \"order\": the cameras, in the calibration's order, to the files in name order")
    trial: str | None = parameter(None, doc="read only the files whose name starts with this: one trial of several side by side "
                                            "(anipose's pose-2d/vid01-camA.h5 beside vid02-camA.h5: trial=\"vid01\")")
    subject: str | None = parameter(None, doc=SUBJECT_DOC)

    #: The file suffixes read, in order of preference: a folder's files of the first suffix it has are used.
    SUFFIXES: ClassVar[tuple[str, ...]] = ()

    @property
    def where(self) -> str:
        """The folder or the files, as the user gave them."""
        return self.folder if self.folder is not None else ", ".join(self.files or ())

    def __attrs_post_init__(self) -> None:
        if (self.folder is None) == (self.files is None):
            raise InputError(f"{self.described}: give either folder (one file per camera) or files, not {'both' if self.folder else 'neither'}")

    @abstractmethod
    def read_table(self, path: Path) -> KeypointTable:
        """One camera's keypoints."""

    def read_edges(self, path: Path) -> tuple[tuple[str, str], ...]:
        """The skeleton edges (pairs of keypoint names) a file declares; none by default."""
        return ()

    def label(self, path: Path) -> str | None:
        """The name ``path`` is matched to a camera by (its name less the suffix), or None when this source does not read it."""
        suffix = next((suffix for suffix in self.SUFFIXES if path.name.lower().endswith(suffix)), None)
        return path.name[: -len(suffix)] if suffix else None

    def keypoint_files(self) -> tuple[Path, dict[Path, Path]]:
        """The folder the files are matched in, and the files by the path named after their camera label."""
        if self.files is not None:
            paths = [Path(path) for path in self.files]
            for path in paths:
                if not path.is_file():
                    raise MissingFileError(f"{self.described}: file {path} does not exist")
                if self.label(path) is None:
                    raise InputError(f"{self.described}: {path} is not a {' or '.join(self.SUFFIXES)} file")
            labels = [self.label(path) for path in paths]
            repeated = sorted({label for label in labels if labels.count(label) > 1})
            if repeated:
                raise InputError(f"{self.described}: several files are named {repeated[0]!r}: name one file per camera")
            return (paths[0].parent if paths else Path(".")), {path.parent / label: path for path, label in zip(paths, labels, strict=True)}
        folder = Path(self.folder)
        if not folder.is_dir():
            raise MissingFileError(f"{self.described}: folder {folder} does not exist")
        for suffix in self.SUFFIXES:
            found = sorted(path for path in folder.iterdir() if path.is_file() and path.name.lower().endswith(suffix))
            if found:
                return folder, {folder / self.label(path): path for path in found}
        return folder, {}

    def observations(self, session: SessionReader, frames: Sequence[int]) -> list[KeypointObservations]:
        """The subject's detections (module docstring) in every camera at ``frames``, in the stored images' pixels."""
        cameras = [session.camera(name) for name in session.camera_names]
        # Matched by name: a stand-in path named after each file's label.
        folder, files = self.keypoint_files()
        matched = {name: files[path] for name, path in match_cameras(session.camera_names, list(files), "keypoint file", folder, self.camera_map,
                                                                   KEYPOINTS_CAMERA_MAP, self.trial).items()}
        recorded = session.recorded_cameras()
        people, edges, names = [], [], None  # people[camera][frame]: [P, L, 3] in the stored images' pixels
        for camera in cameras:
            parts, numbers, table = self.read_table(matched[camera.name])
            if names is not None and parts != names:
                raise InputError(f"{matched[camera.name]}: keypoint names {list(parts)} differ from the other cameras' {list(names)}")
            names = parts
            rows = {int(number): k for k, number in enumerate(numbers)}
            # The camera's video frames, which its table is numbered by (−1, never a row, where it lacks one).
            seen = [detected_people(table[rows[int(number)]]) if int(number) in rows else np.zeros((0, len(parts), 3))
                    for number in session.source_frames(camera.name, frames)]
            people.append(people_to_session_pixels(seen, recorded.get(camera.name), camera))
            edges.append(self.read_edges(matched[camera.name]))
        return subject_observations(session, frames, people, names, self.min_confidence, edges, self.subject)

