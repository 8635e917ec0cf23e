"""2D keypoints of an OpenCap session: each phone's BODY_25 detections, placed in the trial's synchronised
video by the trial's markers, triangulated in the session's cameras.

OpenCap keeps each phone's detections of a trial in ``Videos/CamN/OutputPkl/<trial>_keypoints.pkl``: a list
over the frames of the phone's recording as uploaded (its upright re-encode), each a list of people, each
``{"person_id": [i], "pose_keypoints_2d": [x, y, confidence] × 25}`` in OpenPose's BODY_25 order (its HRNet
detections remapped into it), in the recording's full-size pixels. The session's images are the trial's
synchronised video (:mod:`mmcsplat.storage.opencap_session`): its frame k is the recording's frame k + s, s
the phone's start in the cut, which the download does not keep, at half the size.

- **The start** is found from the trial's markers (``MarkerData/<trial>.trc``), which OpenCap triangulated
  from these detections over the synchronised frames: for each start s the markers' joints that BODY_25
  names are projected into the phone at every synchronised frame k, each frame's person nearest them at
  recording frame k + s is taken, and the median of their distances scores s; the best s is kept. When
  even it leaves the detections more than ``max_misfit`` pixels (of the synchronised video) from the
  markers, or the session has no markers, it is an error: a start cannot be guessed.
- **Pixels**: scaled from the recording's size (the calibration's, which OpenCap states for the recording)
  to the synchronised video's (pixel centres kept), then into the stored images.
- The pickle holds lists, dicts and numbers only, and is read by an unpickler that builds nothing else.
"""

from __future__ import annotations

import logging
import pickle
import warnings
from collections.abc import Sequence
from pathlib import Path

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.plugin_api.parameters import between, finite_positive, parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.calibration import read_rig
from mmcsplat.storage.landmark_formats import read_trc
from mmcsplat.storage.opencap_session import KEYPOINTS_SUFFIX, MARKER_DATA, OUTPUT_PKL, SESSION_VIDEOS, opencap_trial, trc_convention
from mmcsplat.storage.plain_pickle import load_plain
from mmcsplat.storage.session import SessionReader

from .openpose import MODELS
from .subject import SUBJECT_DOC, subject_observations
from .triangulation import TriangulatedKeypoints, people_to_session_pixels

BODY_25 = MODELS["BODY_25"]
#: The detections' least confidence that places the start (OpenCap's own threshold for triangulating them).
PLACING_CONFIDENCE = 0.4

logger = logging.getLogger(__name__)


def keypoints_file(session_folder: Path, camera: str, trial: str) -> Path:
    """Where an OpenCap session keeps ``camera``'s detections of ``trial``."""
    return Path(session_folder) / SESSION_VIDEOS / camera / OUTPUT_PKL / f"{trial}{KEYPOINTS_SUFFIX}"


def read_opencap_keypoints(path: Path) -> list[np.ndarray]:
    """Each recording frame's people [P, 25, 3] (x, y, confidence) of an OpenCap keypoints pickle; errors name
    the file and the frame at fault."""
    try:
        frames = load_plain(Path(path).read_bytes())
    except FileNotFoundError:
        raise MissingFileError(f"OpenCap keypoints {path} do not exist") from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, IndexError) as error:
        raise InputError(f"{path}: not OpenCap's pickle of keypoints ({error})") from None
    if not isinstance(frames, list):
        raise InputError(f"{path}: holds a {type(frames).__name__}, not OpenCap's list of frames")
    people = []
    for k, frame in enumerate(frames):
        try:
            values = [np.asarray(person["pose_keypoints_2d"], dtype=np.float64).reshape(len(BODY_25), 3) for person in frame]
        except (TypeError, KeyError, ValueError):
            raise InputError(f"{path}, frame {k}: not a list of people with pose_keypoints_2d of {3 * len(BODY_25)} numbers") from None
        people.append(np.stack(values) if values else np.zeros((0, len(BODY_25), 3)))
    return people


def scaled(people: list[np.ndarray], factor: float) -> list[np.ndarray]:
    """``people`` with their pixels scaled by ``factor``, pixel centres kept (x → (x + ½)·factor − ½)."""
    result = []
    for frame in people:
        frame = frame.copy()
        frame[..., :2] = (frame[..., :2] + 0.5) * factor - 0.5
        result.append(frame)
    return result


def misfit(people: list[np.ndarray], projected: np.ndarray, start: int) -> tuple[float, float]:
    """How far the markers ``projected`` [T, 25, 2] (NaN where unknown) lie from each synchronised frame's
    nearest person at recording frame k + ``start`` (its confident points): (the median distance once each
    joint's median offset over the frames is taken off, which a calibration's constant error in one phone
    does not bias, so the start is chosen by the motion; the median distance itself). Both infinite where no
    frame has a person."""
    offsets = np.full(projected.shape, np.nan)
    with warnings.catch_warnings():  # people, frames and joints with nothing confident leave all-NaN slices
        warnings.simplefilter("ignore", RuntimeWarning)
        for k, markers in enumerate(projected):
            if not 0 <= k + start < len(people) or not len(people[k + start]):
                continue
            frame = people[k + start]
            gaps = np.where((frame[..., 2] >= PLACING_CONFIDENCE)[..., None], frame[..., :2] - markers[None], np.nan)
            distances = np.nanmedian(np.linalg.norm(gaps, axis=-1), axis=1)
            if np.isfinite(distances).any():
                offsets[k] = gaps[np.nanargmin(distances)]
        if not np.isfinite(offsets).any():
            return np.inf, np.inf
        moving = np.linalg.norm(offsets - np.nanmedian(offsets, axis=0), axis=-1)
        return float(np.nanmedian(moving)), float(np.nanmedian(np.linalg.norm(offsets, axis=-1)))


@attrs.frozen
class OpencapKeypoints(TriangulatedKeypoints):
    """An OpenCap session's 2D keypoints of every phone, placed by its markers, triangulated (module docstring)."""

    path: str = parameter(doc="the OpenCap session's folder (OpenCapData_<id>)", kw_only=True)
    trial: str | None = parameter(None, doc="the trial (the session's only one when unset; the reader's trial in mmcsplat run)")
    min_confidence: float = parameter(0.3, doc="detections below this confidence are not used", validator=between(0, 1))
    max_misfit: float = parameter(10.0, doc="the most pixels (of the synchronised video) the placed detections may lie from the "
                                            "trial's markers", validator=finite_positive)
    subject: str | None = parameter(None, doc=SUBJECT_DOC)

    @property
    def described(self) -> str:
        return f"OpenCap keypoints of {self.path}"

    def observations(self, session: SessionReader, frames: Sequence[int]) -> list[KeypointObservations]:
        """The subject's keypoints in every camera, in the stored images' pixels."""
        folder = Path(self.path)
        trial = opencap_trial(folder, self.trial)
        markers_path = folder / MARKER_DATA / f"{trial}.trc"
        if not markers_path.is_file():
            raise MissingFileError(f"{folder}: no {MARKER_DATA}/{trial}.trc, by which OpenCap's keypoints of trial {trial!r} are placed in "
                                   "its synchronised videos (their recordings' starts are not kept)")
        markers = read_trc(markers_path, trc_convention(session))
        used = [name for name in BODY_25 if name in markers.names]
        if not used:
            raise InputError(f"{markers_path}: none of BODY_25's joints among its markers, to place OpenCap's keypoints by")
        world = np.full((len(markers.positions), len(BODY_25), 3), np.nan)
        world[:, [BODY_25.index(name) for name in used]] = markers.positions[:, [markers.names.index(name) for name in used]]
        calibration = session.provenance.get("reader", {}).get("calibration")
        if calibration is None:
            raise InputError(f"session {session.url}: no calibration in its provenance, to size OpenCap's keypoints by")
        recorded_at = {camera.name: camera for camera in read_rig(Path(calibration)).cameras}
        recorded = session.recorded_cameras()
        people = []
        for name in session.camera_names:
            video = recorded.get(name) or session.camera(name)
            placed = self._placed(keypoints_file(folder, name, trial), video, recorded_at[name], world)
            seen = [placed[k] if 0 <= k < len(placed) else np.zeros((0, len(BODY_25), 3)) for k in session.source_frames(name, frames)]
            people.append(people_to_session_pixels(seen, recorded.get(name), session.camera(name)))
        return subject_observations(session, frames, people, BODY_25, self.min_confidence, subject=self.subject)

    def _placed(self, path: Path, video: Camera, recording: Camera, world: np.ndarray) -> list[np.ndarray]:
        """One phone's detections by synchronised frame, in the synchronised video's pixels."""
        people = scaled(read_opencap_keypoints(path), video.width / recording.width)
        projected = np.full(world.shape[:2] + (2,), np.nan)
        known = np.isfinite(world).all(axis=-1)
        projected[known] = video.project(world[known])
        scores = [misfit(people, projected, start) for start in range(max(len(people) - len(world), 0) + 1)]
        best = int(np.argmin([moving for moving, _ in scores]))
        if not scores[best][1] <= self.max_misfit:
            raise InputError(f"{path}: no start in its recording puts its detections within {self.max_misfit:g} px of the trial's markers "
                             f"(the best, frame {best}, leaves them {scores[best][1]:.3g} px off): are these the trial's detections?")
        logger.info("%s: the synchronised video starts at its recording's frame %d (%.2f px from the markers, %.2f px once each joint's "
                    "median offset is taken off)", path, best, scores[best][1], scores[best][0])
        return people[best:]
