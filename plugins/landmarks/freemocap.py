"""2D keypoints as FreeMoCap stores them, one NumPy file for every camera, triangulated in the session's cameras.

A FreeMoCap recording keeps its trackers' 2D detections in
``output_data/raw_data/{tracker}_2dData_numCams_numFrames_numTrackedPoints_pixelXY.npy`` (FreeMoCap 1.4 on;
before it ``mediapipe2dData_numCams_numFrames_numTrackedPoints_pixelXY.npy``, the name FreeMoCap itself still
falls back to): an array [cameras, frames, points, 3] of x, y in the pixels of the recording's
``synchronized_videos`` and a third value that is not a confidence (MediaPipe's relative depth; YOLO's NaN).
Row k of a camera is the k-th frame of its video. Undetected points are NaN; FreeMoCap stores no confidence,
so a detected point counts as confidence 1.

- **Points**: MediaPipe Holistic's 553 (the body's 33, then both hands and the face; only the body is read,
  which comes first in every FreeMoCap version) or YOLO's 17 COCO keypoints, told apart by the count. Their
  names become OpenPose's where OpenPose has the joint (``left_knee`` → ``LKnee``; MediaPipe's
  ``left_foot_index``, the tip of the foot, → ``LBigToe``), so the masks, body parts and movement
  measures that know a human body by OpenPose's names know this one; the others keep MediaPipe's names.
- **Pixels**: MediaPipe's normalised coordinates times the image size put a pixel's centre at +0.5, so
  0.5 is taken off to reach OpenCV's (and mmcsplat's) integer centres.
- **Cameras**: the array's cameras are the recording's ``synchronized_videos/*.mp4`` in FreeMoCap's order
  (names sorted ignoring case: FreeMoCap ≥ 1.6 and its tracker sort them so; earlier versions took the
  folder's listing order, which ``camera_order`` states where it differed); each session camera is the
  video it was ingested from, or for a session made elsewhere the video its name matches (or ``camera_map``
  names).

FreeMoCap records no skeleton edges; the ``keypoints`` segmenter draws a human from OpenPose's names.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.plugin_api.parameters import parameter
from mmcsplat.scene.human_skeleton import openpose_name
from mmcsplat.storage.camera_names import KEYPOINTS_CAMERA_MAP, match_cameras
from mmcsplat.storage.session import SessionReader

from .keypoint_models import COCO, MEDIAPIPE_BODY
from .subject import SUBJECT_DOC, subject_observations
from .triangulation import DETECTED, TriangulatedKeypoints, detected_people, people_to_session_pixels

#: Where a recording keeps its videos, beside ``output_data``.
VIDEOS = "synchronized_videos"

#: MediaPipe Holistic's points as FreeMoCap stores them: the body, the right and left hands, the face with its irises.
MEDIAPIPE_POINTS = 33 + 21 + 21 + 478
#: MediaPipe's pixel centres are at +0.5 (module docstring).
PIXEL_CENTRE = 0.5


def read_freemocap_2d(path: Path) -> tuple[tuple[str, ...], np.ndarray]:
    """(keypoint names, [cameras, frames, K, 3] x, y with OpenCV's integer centres and :data:`DETECTED`, NaN where
    undetected) of the body in a FreeMoCap 2D file."""
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise InputError(f"{path}: not a NumPy array file ({error})") from None
    if data.ndim != 4 or data.shape[3] not in (2, 3):
        raise InputError(f"{path}: shape {list(data.shape)}, expected [cameras, frames, points, 3] as FreeMoCap writes it")
    if data.shape[2] == MEDIAPIPE_POINTS:
        names = MEDIAPIPE_BODY
    elif data.shape[2] == len(COCO):
        names = COCO
    else:
        raise InputError(f"{path}: {data.shape[2]} points, neither MediaPipe Holistic's {MEDIAPIPE_POINTS} nor YOLO's {len(COCO)}: "
                         "no names known for them")
    pixels = data[:, :, :len(names), :2].astype(np.float64) - PIXEL_CENTRE
    return tuple(openpose_name(name) for name in names), np.concatenate([pixels, np.full((*pixels.shape[:3], 1), DETECTED)], axis=-1)


@attrs.frozen
class FreeMoCapKeypoints(TriangulatedKeypoints):
    """FreeMoCap's 2D keypoints of every camera, from one file, triangulated (module docstring)."""

    path: str = parameter(doc="the 2D file (output_data/raw_data/mediapipe_2dData_numCams_numFrames_numTrackedPoints_pixelXY.npy)",
                          kw_only=True)
    videos: str | None = parameter(None, doc="the recording's synchronized_videos folder, whose videos are the file's cameras (default: "
                                             "the one beside the file's output_data)")
    camera_map: dict | None = parameter(None, doc="session camera name → its video's name (without .mp4), where a session not made from "
                                             "these videos names its cameras otherwise")
    camera_order: tuple[str, ...] | None = parameter(None, doc="the file's cameras in its order, by the session's names, where FreeMoCap's "
                                                              "order was not the videos' names sorted (recordings before FreeMoCap 1.6)")
    subject: str | None = parameter(None, doc=SUBJECT_DOC)

    @property
    def described(self) -> str:
        return f"FreeMoCap keypoints {self.path}"

    def _videos_folder(self) -> Path:
        if self.videos is not None:
            return Path(self.videos)
        path = Path(self.path).resolve()
        return path.parents[2] / VIDEOS if len(path.parents) > 2 else path.parent / VIDEOS

    def rows(self, session: SessionReader, count: int) -> dict[str, int]:
        """Each session camera's row of the file's ``count`` cameras."""
        if self.camera_order is not None:
            if len(set(self.camera_order)) != len(self.camera_order) or len(self.camera_order) != count or \
                    not set(session.camera_names) <= set(self.camera_order):
                raise InputError(f"{self.path}: camera_order {list(self.camera_order)} must name the file's {count} cameras once each, in "
                                 f"its order, the session's ({', '.join(session.camera_names)}) among them")
            return {name: k for k, name in enumerate(self.camera_order)}
        folder = self._videos_folder()
        if not folder.is_dir():
            raise MissingFileError(f"{self.path}: the recording's videos, which order its cameras, are not at {folder}: give videos=FOLDER "
                                   "or camera_order")
        videos = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() == ".mp4"), key=lambda p: p.name.lower())
        if len(videos) != count:
            raise InputError(f"{self.path}: {count} cameras, but {folder} holds {len(videos)} .mp4 videos "
                             f"({', '.join(p.name for p in videos) or 'none'}): give camera_order")
        row = {path.name: k for k, path in enumerate(videos)}
        # The video each camera was ingested from, where the session came from these videos; else matched by name.
        ingested = {name: Path(video).name for name, video in session.provenance.get("reader", {}).get("videos", {}).items()}
        if all(ingested.get(name) in row for name in session.camera_names):
            return {name: row[ingested[name]] for name in session.camera_names}
        labels = {folder / path.stem: path for path in videos}
        matched = match_cameras(session.camera_names, list(labels), "FreeMoCap video", folder, self.camera_map, KEYPOINTS_CAMERA_MAP)
        return {name: row[labels[label].name] for name, label in matched.items()}

    def observations(self, session: SessionReader, frames: Sequence[int]) -> list[KeypointObservations]:
        """The subject's keypoints in every camera, in the stored images' pixels."""
        path = Path(self.path)
        if not path.is_file():
            raise MissingFileError(f"freemocap keypoints: file {path} does not exist")
        names, keypoints = read_freemocap_2d(path)
        rows = self.rows(session, len(keypoints))
        recorded = session.recorded_cameras()
        people = []  # [camera][frame]: [P, L, 3] in the stored images' pixels
        for name in session.camera_names:
            table = keypoints[rows[name]]
            seen = [detected_people(table[number][None]) if 0 <= number < len(table) else np.zeros((0, len(names), 3))
                    for number in session.source_frames(name, frames)]
            people.append(people_to_session_pixels(seen, recorded.get(name), session.camera(name)))
        return subject_observations(session, frames, people, names, DETECTED, subject=self.subject)
