"""2D keypoints in OpenPose's JSON, as OpenPose and Pose2Sim write them, triangulated in the session's cameras.

Layout: one folder per camera under ``folder`` (``pose_2d/cam01/…``, or OpenPose's ``cam01_json``, matched
to the session's cameras by name like videos: ``cam01`` ↔ ``cam_01`` ↔ ``int_cam01_img``, or by
``camera_map``), each holding one JSON file per frame whose last number is the frame's in the camera's video
or image folder (``cam01.0042.json``, ``…_000000000042_keypoints.json``; Pose2Sim's ``frame_0001_000000.json``, the
image's position from 0). OpenPose run on an image folder names each file after its image instead
(``frame_0001_keypoints.json``): where a session made from images still finds its images, such a file is the
frame of the image it is named after, whatever the first image's number (ffmpeg numbers from 1). Each file lists ``people``, each with ``pose_keypoints_2d`` = [x, y, confidence] × K
in the source video's pixels; the ``model`` names the K keypoints (BODY_25B, the model Pose2Sim's demo
uses, or BODY_25, OpenPose's default), or ``auto`` tells them apart by the detections: both have 25
keypoints, and BODY_25's keypoint 8 (MidHip) lies between its 9 and 12 (the hips), where BODY_25B's
(a right elbow) lies far from the midpoint of its 9 and 12 (a left wrist and a right hip): read as the other,
each model's knees would be taken for ankles. A frame missing a file or a person has no detections (confidence 0).

Several people: the subject is the person the cameras agree on (:mod:`.subject`): the detections of one
person triangulate consistently, followed from frame to frame, and a camera that sees only others gives no
detections that frame.

The detections are mapped into the stored images and triangulated by :mod:`.triangulation`.
"""

from __future__ import annotations

import functools
import json
import logging
import re
import warnings
from collections.abc import Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.plugin_api.parameters import between, one_of, parameter
from mmcsplat.storage.camera_names import KEYPOINTS_CAMERA_MAP, match_cameras, natural_key
from mmcsplat.storage.session import SessionReader

from .subject import SUBJECT_DOC, subject_observations
from .triangulation import TriangulatedKeypoints, people_to_session_pixels

logger = logging.getLogger(__name__)

#: Keypoint names by index, per model (OpenPose's documented orders).
MODELS = {
    "BODY_25B": ("Nose", "LEye", "REye", "LEar", "REar", "LShoulder", "RShoulder", "LElbow", "RElbow", "LWrist", "RWrist",
                 "LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle", "Neck", "Head", "LBigToe", "LSmallToe", "LHeel",
                 "RBigToe", "RSmallToe", "RHeel"),
    "BODY_25": ("Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "MidHip", "RHip", "RKnee",
                "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar", "LBigToe", "LSmallToe", "LHeel",
                "RBigToe", "RSmallToe", "RHeel"),
}


#: The keypoint count every model of :data:`MODELS` has.
KEYPOINT_COUNT = 25
AUTO_MODEL = "auto"
#: BODY_25's MidHip lies within this share of the hips' distance from their midpoint (its median over the detections), where
#: BODY_25B's keypoint 8 does not: on the Pose2Sim demo's BODY_25B detections that median is 1.08; BODY_25's MidHip is
#: OpenPose's estimate of that very midpoint.
MIDHIP_SHARE = 0.5
#: Person-frames with keypoints 8, 9 and 12 confident that :func:`body_model` needs to tell the models apart.
MODEL_EVIDENCE = 10
#: Files of each camera's folder that ``auto`` reads to tell the models apart, spread over its frames.
MODEL_SAMPLE = 30


def body_model(people: Sequence[np.ndarray], min_confidence: float) -> str | None:
    """``BODY_25`` or ``BODY_25B`` as the detections ``people`` (each file's [P, 25, 3]) show it (module
    docstring); None with fewer than :data:`MODEL_EVIDENCE` person-frames to tell by."""
    rows = np.concatenate([np.zeros((0, KEYPOINT_COUNT, 3)), *people])
    rows = rows[(rows[:, [8, 9, 12], 2] >= min_confidence).all(axis=1)]
    if len(rows) < MODEL_EVIDENCE:
        return None
    span = np.linalg.norm(rows[:, 9, :2] - rows[:, 12, :2], axis=1)
    share = np.linalg.norm(rows[:, 8, :2] - (rows[:, 9, :2] + rows[:, 12, :2]) / 2, axis=1) / np.maximum(span, 1e-9)
    return "BODY_25" if np.median(share) < MIDHIP_SHARE else "BODY_25B"


@functools.lru_cache(maxsize=16)
def folder_model(folder: Path, min_confidence: float) -> str:
    """:func:`body_model` of up to :data:`MODEL_SAMPLE` files of each camera folder in ``folder``, spread over
    its frames; BODY_25B with a warning where they cannot tell: the same answer for every frame range read, found
    (and said) once however often a run reads the folder (masks, guidance, scoring)."""
    files = []
    for camera in sorted(path for path in folder.iterdir() if path.is_dir()):
        found = sorted(camera.glob("*.json"), key=lambda path: natural_key(path.name))
        files += [found[int(i)] for i in np.unique(np.linspace(0, len(found) - 1, MODEL_SAMPLE).round())] if found else []
    model = body_model([read_people(path, KEYPOINT_COUNT) for path in files], min_confidence)
    if model is None:
        warnings.warn(f"openpose keypoints {folder}: too few confident detections to tell BODY_25 from BODY_25B: read as BODY_25B "
                      "(set the source's model to say which)", stacklevel=2)
        return "BODY_25B"
    logger.info("openpose keypoints %s: read as %s (keypoint 8 %s the hips' midpoint)", folder, model, "at" if model == "BODY_25" else "away from")
    return model


def frame_number(path: Path) -> int | None:
    """The last run of digits in a file's stem: the frame number OpenPose and Pose2Sim write there."""
    numbers = re.findall(r"\d+", path.stem)
    return int(numbers[-1]) if numbers else None


def image_named(session: SessionReader, camera: str, files: Sequence[Path]) -> dict[int, Path]:
    """The ``files`` OpenPose named after ``camera``'s images (``{image stem}_keypoints.json``, from ``--image_dir``)
    by the capture frame of their image (the image's number less the capture's first); empty where the session was
    not made from numbered images, its images are gone, or no file is named so."""
    reader = session.provenance.get("reader", {})
    first, folder = reader.get("first_number"), reader.get("folders", {}).get(camera)
    if first is None or folder is None:
        return {}
    if not Path(folder).is_dir():
        if first != 0 and any(path.stem.endswith("_keypoints") for path in files):
            warnings.warn(f"{files[0].parent}: OpenPose names an image's keypoints after the image, but camera {camera!r}'s images "
                          f"are no longer at {folder} to tell which: read by position instead, {first} frame(s) late if these files are "
                          f"named after images numbered from {first}", stacklevel=3)
        return {}
    stems = {path.stem for path in Path(folder).iterdir() if path.is_file()}
    named = {}
    for path in files:
        image = path.stem.removesuffix("_keypoints")
        number = frame_number(Path(image))
        if image != path.stem and image in stems and number is not None:
            named[number - first] = path
    return named


def read_people(path: Path, count: int) -> np.ndarray:
    """[P, count, 3] (x, y, confidence) of every person in one OpenPose JSON file; a point with a null or NaN
    value is undetected (all zero)."""
    try:
        people = json.loads(path.read_text())["people"]
        rows = [np.asarray(person["pose_keypoints_2d"], dtype=np.float64) for person in people]
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise InputError(f"{path}: not an OpenPose keypoint file ({type(error).__name__}: {error})") from None
    for index, row in enumerate(rows):
        if row.size != 3 * count:
            raise InputError(f"{path}: person {index} has {row.size // 3} keypoints, the model has {count}")
    detected = np.stack(rows).reshape(len(rows), count, 3) if rows else np.zeros((0, count, 3))
    detected[~np.isfinite(detected).all(axis=-1)] = 0.0  # a writer's null or NaN for a point it did not find: no detection
    return detected


@attrs.frozen
class OpenPoseKeypoints(TriangulatedKeypoints):
    """OpenPose JSON keypoints per camera, triangulated (module docstring)."""

    folder: str = parameter(doc="the folder of per-camera keypoint folders (Pose2Sim: pose_2d)", kw_only=True)
    model: str = parameter(AUTO_MODEL, doc="the keypoint model, which names the keypoints: BODY_25B (Pose2Sim's), BODY_25 (OpenPose's "
                                        "default), or auto: told apart by where keypoint 8 lies", validator=one_of(AUTO_MODEL, *MODELS))
    min_confidence: float = parameter(0.3, doc="detections below this confidence are not used", validator=between(0, 1))
    camera_map: dict | str | None = parameter(None, doc="session camera name → its keypoint folder's name, where the names differ; or "
                                               "\"order\": the cameras, in the calibration's order, to the folders in name order")
    subject: str | None = parameter(None, doc=SUBJECT_DOC)

    @property
    def described(self) -> str:
        return f"OpenPose keypoints {self.folder} ({self.resolved_model})"

    def observations(self, session: SessionReader, frames: Sequence[int]) -> list[KeypointObservations]:
        """The subject's keypoints (:mod:`.subject`) in every camera with a folder, in the stored images' pixels."""
        folder = Path(self.folder)
        if not folder.is_dir():
            raise MissingFileError(f"openpose keypoints: folder {folder} does not exist")
        cameras = [session.camera(name) for name in session.camera_names]
        # OpenPose and older Pose2Sim name a camera's folder CAMERA_json: the suffix is not part of the name.
        by_label = {folder / re.sub(r"_json$", "", path.name): path for path in folder.iterdir() if path.is_dir()}
        matched = match_cameras(session.camera_names, list(by_label), "keypoint folder", folder, self.camera_map, KEYPOINTS_CAMERA_MAP)
        folders = {name: by_label[label] for name, label in matched.items()}
        recorded = session.recorded_cameras()
        people = []  # [camera][frame]: [P, L, 3] in the stored images' pixels
        for camera in cameras:
            found = sorted(folders[camera.name].glob("*.json"), key=lambda p: natural_key(p.name))
            by_image = image_named(session, camera.name, found)
            if by_image:
                files, numbers = by_image, session.capture_frames(frames)  # a frame the camera lacks has no image, so no such file
            else:  # numbered by the camera's own frames: its video's, or its images' positions
                files, numbers = {frame_number(path): path for path in found}, session.source_frames(camera.name, frames)
            held = numbers[numbers >= 0]
            if len(held) and not any(int(number) in files for number in held):
                raise MissingFileError(f"{folders[camera.name]}: no keypoint file numbered like the session's frames "
                                       f"{int(held[0])}–{int(held[-1])}")
            seen = [read_people(files[int(number)], KEYPOINT_COUNT) if int(number) in files else np.zeros((0, KEYPOINT_COUNT, 3))
                    for number in numbers]
            people.append(people_to_session_pixels(seen, recorded.get(camera.name), camera))
        return subject_observations(session, frames, people, MODELS[self.resolved_model], self.min_confidence, subject=self.subject)

    @property
    def resolved_model(self) -> str:
        """The model named, or the one the detections of the folder's camera folders show, whichever frames are
        read (:func:`folder_model`); BODY_25B, with a warning, where they are too few to tell."""
        folder = Path(self.folder)
        return folder_model(folder.resolve(), self.min_confidence) if self.model == AUTO_MODEL and folder.is_dir() else self.model
