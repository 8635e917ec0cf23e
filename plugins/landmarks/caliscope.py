"""2D keypoints as Caliscope writes them, one CSV of every camera, triangulated in the session's cameras.

Caliscope's reconstruction of a recording with a body tracker writes ``<recording>/<TRACKER>/xy_<TRACKER>.csv``
beside the recording's ``cam_N.mp4`` videos: one row per detected point, columns ``cam_id`` (N of ``cam_N.mp4``;
``port`` in versions before 0.7, whose videos are ``port_N.mp4``), ``frame_index`` (the frame of that camera's
video), ``keypoint_id`` (``point_id`` before 0.10) and ``img_loc_x``, ``img_loc_y`` in the video's pixels, among
others. Caliscope stores no confidence and leaves out points its tracker was unsure of (under its model card's
threshold, 0.3 for its own), so a point present counts as confidence 1 and an absent one as undetected.

- **Names**: a keypoint id is named by the tracker's model card, its ``[points]`` table (``name = id``): the
  card given as ``model_card``, else Caliscope's own by the tracker's name — ``ONNX_rtmpose_*_halpe26`` (Halpe's
  26), ``ONNX_rtmpose_*_coco_wholebody`` (COCO-WholeBody's body and feet; its face and hands are not read), and
  the MediaPipe trackers of Caliscope before 0.10 (``POSE``; ``HOLISTIC`` and ``SIMPLE_HOLISTIC``, whose ids
  0–32 are the body's and from 100 the hands' and face's, not read). Names become OpenPose's where OpenPose
  has the joint (:func:`~mmcsplat.scene.human_skeleton.openpose_name`).
- **Cameras**: each session camera is ``cam_id`` N of the video it was ingested from (``cam_N.mp4``), or of its
  name (``cam_N``, as mmcsplat names Caliscope's cameras).
- **Pixels**: as written (Caliscope maps its trackers' points back into the unrotated, distorted video frame).
"""

from __future__ import annotations

import csv
import re
import tomllib
from collections.abc import Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.plugin_api.parameters import parameter
from mmcsplat.scene.human_skeleton import openpose_name
from mmcsplat.storage.session import SessionReader

from .keypoint_models import COCO_WHOLEBODY_BODY, HALPE26, MEDIAPIPE_BODY
from .subject import SUBJECT_DOC, subject_observations
from .triangulation import DETECTED, TriangulatedKeypoints, people_to_session_pixels

#: Each built-in body tracker's names by keypoint id, by a pattern its name matches.
TRACKER_POINTS = ((re.compile(r"ONNX_.*halpe26$"), HALPE26), (re.compile(r"ONNX_.*coco_wholebody$"), COCO_WHOLEBODY_BODY),
                  (re.compile(r"(POSE|HOLISTIC|SIMPLE_HOLISTIC)$"), MEDIAPIPE_BODY))
#: A column's name in each Caliscope version, the current first.
COLUMNS = {"camera": ("cam_id", "port"), "frame": ("frame_index",), "point": ("keypoint_id", "point_id"), "x": ("img_loc_x",),
           "y": ("img_loc_y",)}
_CAMERA_NUMBER = re.compile(r"(?:cam|port)_(\d+)$")


def tracker_of(path: Path) -> str:
    """The tracker a ``xy_<TRACKER>.csv`` file is named after."""
    return path.stem.removeprefix("xy_")


def point_names(tracker: str, model_card: Path | None) -> dict[int, str]:
    """Keypoint id → name: the ``[points]`` table of ``model_card`` where given, else the built-in tracker's."""
    if model_card is not None:
        try:
            points = tomllib.loads(model_card.read_text(encoding="utf-8"))["points"]
            return {int(index): str(name) for name, index in points.items()}
        except (OSError, tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as error:
            raise InputError(f"model card {model_card}: no [points] table of name = id ({type(error).__name__}: {error})") from None
    for pattern, names in TRACKER_POINTS:
        if pattern.match(tracker):
            return dict(enumerate(names))
    raise InputError(f"Caliscope tracker {tracker!r}: its keypoints' names are not known here (Halpe26 and COCO-WholeBody RTMPose "
                     "and MediaPipe POSE/HOLISTIC are): give its model card, model_card=FILE.toml")


def read_caliscope_xy(path: Path, names: dict[int, str]) -> tuple[tuple[str, ...], dict[int, dict[int, np.ndarray]]]:
    """(the named keypoints, in id order; camera number → video frame → [K, 3] x, y, 1 where detected, else 0) of
    a Caliscope ``xy_*.csv``; ids without a name are left out."""
    ids = sorted(names)
    column = {index: k for k, index in enumerate(ids)}
    table: dict[int, dict[int, np.ndarray]] = {}
    try:
        with path.open(newline="", encoding="utf-8") as file:
            reader = csv.DictReader(file)
            header = reader.fieldnames or []
            found = {key: next((name for name in options if name in header), None) for key, options in COLUMNS.items()}
            missing = [options[0] for key, options in COLUMNS.items() if found[key] is None]
            if missing:
                raise InputError(f"{path}: no {', '.join(missing)} column (it has {', '.join(header) or 'none'}): not a Caliscope "
                                 "tracker's 2D output of a recording")
            for line, row in enumerate(reader, start=2):
                try:
                    point = int(row[found["point"]])
                    if point not in column:
                        continue
                    camera, frame = int(row[found["camera"]]), int(row[found["frame"]])
                    xy = float(row[found["x"]]), float(row[found["y"]])
                except (TypeError, ValueError):
                    raise InputError(f"{path}, line {line}: not numbers: {dict(row)}") from None
                points = table.setdefault(camera, {}).setdefault(frame, np.zeros((len(ids), 3)))
                points[column[point]] = (*xy, DETECTED)
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise InputError(f"{path}: not a readable CSV file ({error})") from None
    return tuple(openpose_name(names[index]) for index in ids), table


@attrs.frozen
class CaliscopeKeypoints(TriangulatedKeypoints):
    """Caliscope's 2D keypoints of every camera, from one CSV, triangulated (module docstring)."""

    path: str = parameter(doc="the tracker's 2D file (RECORDING/TRACKER/xy_TRACKER.csv)", kw_only=True)
    model_card: str | None = parameter(None, doc="the tracker's model card (a TOML file with a [points] table of name = id), for a "
                                                 "tracker other than Caliscope's own")
    subject: str | None = parameter(None, doc=SUBJECT_DOC)

    @property
    def described(self) -> str:
        return f"Caliscope keypoints {self.path}"

    def camera_numbers(self, session: SessionReader) -> dict[str, int]:
        """Each session camera's ``cam_id``: its ingested video's number, else its name's."""
        videos = session.provenance.get("reader", {}).get("videos", {})
        numbers = {}
        for name in session.camera_names:
            match = _CAMERA_NUMBER.search(Path(videos.get(name, "")).stem) or _CAMERA_NUMBER.search(name)
            if match is None:
                raise InputError(f"{self.path}: camera {name!r} is neither ingested from a cam_N.mp4 video nor named cam_N, so its "
                                 "cam_id is not known")
            numbers[name] = int(match.group(1))
        return numbers

    def observations(self, session: SessionReader, frames: Sequence[int]) -> list[KeypointObservations]:
        """The subject's keypoints in every camera, in the stored images' pixels."""
        path = Path(self.path)
        if not path.is_file():
            raise MissingFileError(f"caliscope keypoints: file {path} does not exist")
        names, table = read_caliscope_xy(path, point_names(tracker_of(path), Path(self.model_card) if self.model_card else None))
        numbers = self.camera_numbers(session)
        absent = sorted(name for name, number in numbers.items() if number not in table)
        if len(absent) == len(numbers):
            raise InputError(f"{path}: no detections of cam_id {', '.join(str(numbers[name]) for name in absent)} (it holds cam_id "
                             f"{', '.join(map(str, sorted(table))) or 'none'})")
        recorded = session.recorded_cameras()
        people = []  # [camera][frame]: [P, L, 3] in the stored images' pixels
        for name in session.camera_names:
            rows = table.get(numbers[name], {})
            seen = [rows[int(number)][None] if int(number) in rows else np.zeros((0, len(names), 3))
                    for number in session.source_frames(name, frames)]
            people.append(people_to_session_pixels(seen, recorded.get(name), session.camera(name)))
        return subject_observations(session, frames, people, names, DETECTED, subject=self.subject)
