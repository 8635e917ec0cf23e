"""Which of the people detected in each camera is the subject: the person the cameras agree on.

A 2D detector reports everyone it sees: a parent's or a clinician's arms beside an infant, a bystander at the
edge of two of the Pose2Sim demo's cameras. Each camera's most confident person, taken on its own, is whoever
the detector sees best, which need not be the subject, nor the same person in every camera, nor in every
frame. Here, in each frame:

- two cameras' detections whose triangulation reprojects onto both within :data:`AGREEMENT` of the image's
  diagonal (median over their common keypoints, at least :data:`FEWEST_KEYPOINTS`) are a person; every other
  camera's detection that reprojects as closely joins them, and the person is triangulated again from all;
- a detection belongs to one person at most: the people seen by more cameras, then the closer-agreeing, first;
- the subject is the person nearest the subject of the frame before (the centroid of its keypoints), and in
  its first frame the person nearest the point the cameras look at (:func:`rig_focus`), or, given a pixel on
  the subject in one camera (a source's ``subject``: :func:`subject_hint`), the person whose centroid
  projects nearest that pixel — a parent nearer the rig's centre than the infant, two people in one room;
- a camera none of whose detections belongs to the subject gives none that frame; in each other camera the
  detections that agree with the subject's skeleton (within the tolerance, and no other person's) are the
  subject's: a detector that split the subject in two (OpenPose at cam_01's frame 37 of the demo: the upper
  body and the legs apart) has them joined, each keypoint from the part most confident of it; a camera that
  does not judge (a held-out one) takes them too, but does not help find the people;
- a frame where no two cameras agree on anyone takes, in each camera, the detection nearest the subject's
  last skeleton reprojected (within the same tolerance), and before any subject was found the most confident.

Written here because no installed package associates people across calibrated views (Pose2Sim does it inside
its own pipeline, not as a library call).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations

import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import KeypointObservations
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.triangulation import triangulate
from mmcsplat.storage.session import SessionReader

from .triangulation import to_session_pixels

#: How far a person's detection may lie from its triangulated skeleton reprojected, as a share of the image's
#: diagonal (the median over its keypoints): 5 %, 27 px in a 270 × 480 image, where one person's detections
#: in the Pose2Sim demo lie 2–5 px from their triangulation and its bystander a third of the image away.
AGREEMENT = 0.05
#: Keypoints two detections must share to be compared.
FEWEST_KEYPOINTS = 3

#: One camera's detections in one frame: [P, L, 3] (x, y, confidence) in the camera's pixels.
Detections = np.ndarray


def rig_focus(cameras: Sequence[Camera]) -> np.ndarray:
    """The point nearest every camera's optical axis (least squares): where a ring of cameras looks."""
    normal = np.zeros((3, 3))
    target = np.zeros(3)
    for camera in cameras:
        axis = np.asarray(camera.R)[2]  # the optical axis in world coordinates
        across = np.eye(3) - np.outer(axis, axis)
        normal += across
        target += across @ camera.center
    return np.linalg.lstsq(normal, target, rcond=None)[0]


#: The keypoint sources' ``subject`` parameter, documented once.
SUBJECT_DOC = ("which person (or animal) is the subject where several are detected: \"CAMERA:X,Y\", a pixel of CAMERA's video that "
               "lies on the subject at the first frame (default: the one nearest the point the cameras look at)")
#: A pixel on the subject in one camera: (the camera's index among the cameras, [2] pixel of the stored image).
SubjectHint = tuple[int, np.ndarray]


def subject_hint(session: SessionReader, subject: str | None) -> SubjectHint | None:
    """A source's ``subject`` parameter, ``"CAMERA:X,Y"`` (a pixel of CAMERA's recorded video that lies on the
    subject at the first frame), as a :data:`SubjectHint` in the session's stored pixels; None for None."""
    if subject is None:
        return None
    camera, _, pixel = str(subject).partition(":")
    try:
        x, y = (float(value) for value in pixel.split(","))
    except ValueError:
        raise InputError(f"keypoints subject {subject!r}: give CAMERA:X,Y, a pixel of the camera's video that lies on the subject at the "
                         f"first frame (e.g. {session.camera_names[0]}:540,960)") from None
    if camera not in session.camera_names:
        raise InputError(f"keypoints subject {subject!r}: the session has no camera {camera!r} (it has {', '.join(session.camera_names)})")
    stored = session.camera(camera)
    recorded = session.recorded_cameras().get(camera)
    point = np.array([[x, y]])
    return session.camera_names.index(camera), (to_session_pixels(point, recorded, stored) if recorded is not None else point)[0]


def choose_subject(people: Sequence[Sequence[Detections]], cameras: Sequence[Camera], min_confidence: float,
                   judges: Sequence[bool] | None = None, hint: SubjectHint | None = None) -> list[list[tuple[int, ...]]]:
    """``chosen[c][t]``: the indices of the subject's detections among ``people[c][t]`` (camera c's detections
    at frame t, keypoints under ``min_confidence`` unused), empty where camera c did not see it (module
    docstring): several where the detector split the subject in two (:func:`merge_detections` joins them).

    Only the cameras ``judges`` marks (every camera by default) find the people; each other camera then takes
    its detections that agree with the subject's skeleton. The keypoint sources pass the session's training
    cameras, so that a held-out camera never decides which detection another camera gives. A ``hint`` picks
    the first frame's subject instead of the rig's focus."""
    judges = [True] * len(cameras) if judges is None else list(judges)
    tolerances = [AGREEMENT * float(np.hypot(camera.width, camera.height)) for camera in cameras]
    agreement = _Agreement(cameras, tolerances, min_confidence)
    focus = rig_focus([camera for camera, judging in zip(cameras, judges, strict=True) if judging] or cameras)
    frames = len(people[0]) if people else 0
    chosen: list[list[tuple[int, ...]]] = [[()] * frames for _ in cameras]
    last: np.ndarray | None = None
    for t in range(frames):
        frame = [people[c][t] for c in range(len(cameras))]
        persons = agreement.persons([detections if judges[c] else detections[:0] for c, detections in enumerate(frame)])
        members: dict[int, int] = {}
        others: set[tuple[int, int]] = set()
        if persons:
            if last is None and hint is not None:
                camera, pixel = cameras[hint[0]], hint[1]
                subject = min(persons, key=lambda person: float(np.linalg.norm(camera.project(_centroid(person[1])[None])[0] - pixel)))
            else:
                reference = focus if last is None else _centroid(last)
                subject = min(persons, key=lambda person: float(np.linalg.norm(_centroid(person[1]) - reference)))
            members, last = subject
            others = {pair for person in persons if person is not subject for pair in person[0].items()}
        for c, detections in enumerate(frame):
            if not len(detections) or (members and judges[c] and c not in members):
                continue  # a judging camera outside the subject's members sees only others
            if last is None:
                chosen[c][t] = (int(np.argmax(detections[:, :, 2].mean(axis=1))),)
                continue
            errors = [agreement.error(c, last, detection) for detection in detections]
            agreeing = [int(k) for k in np.argsort(errors, kind="stable") if errors[k] <= tolerances[c] and (c, k) not in others]
            if c in members and members[c] not in agreeing:  # a member whose error grew past the tolerance with the others' refit
                agreeing.insert(0, members[c])
            chosen[c][t] = tuple(agreeing)
    return chosen


def subject_observations(session: SessionReader, frames: Sequence[int], people: Sequence[Sequence[Detections]], names: Sequence[str],
                         min_confidence: float, edges: Sequence[tuple[tuple[str, str], ...]] | None = None,
                         subject: str | None = None) -> list[KeypointObservations]:
    """The subject's keypoints in every camera of ``session`` (in its order), from ``people[c][k]``: camera c's
    detections at ``frames[k]`` in the stored images' pixels (:func:`choose_subject`, judged by the training
    cameras, the first frame's subject picked by the ``subject`` pixel where given: :func:`subject_hint`;
    :func:`merge_detections`). Confidences under ``min_confidence`` become 0; ``edges[c]`` are the skeleton
    edges camera c's file declares."""
    cameras = [session.camera(name) for name in session.camera_names]
    chosen = choose_subject(people, cameras, min_confidence, [name not in session.heldout for name in session.camera_names],
                            subject_hint(session, subject))
    result = []
    for c, camera in enumerate(cameras):
        subject = np.stack([merge_detections(people[c][k], chosen[c][k]) for k in range(len(frames))])
        confidence = np.where(subject[..., 2] < min_confidence, 0.0, subject[..., 2])
        result.append(KeypointObservations(camera.name, tuple(names), frames, subject[..., :2], confidence, edges[c] if edges else ()))
    return result


def merge_detections(detections: Detections, indices: Sequence[int]) -> np.ndarray:
    """[L, 3] one person's keypoints from its detections ``indices`` of ``detections`` [P, L, 3]: each keypoint
    from the detection most confident of it (zeros, undetected, when there are none)."""
    if not indices:
        return np.zeros(detections.shape[1:])
    parts = detections[list(indices)]
    best = np.argmax(parts[:, :, 2], axis=0)
    return parts[best, np.arange(parts.shape[1])]


def _centroid(skeleton: np.ndarray) -> np.ndarray:
    return np.nanmean(skeleton, axis=0)


class _Agreement:
    """The people that one frame's detections in several cameras agree on."""

    def __init__(self, cameras: Sequence[Camera], tolerances: Sequence[float], min_confidence: float) -> None:
        self.cameras = list(cameras)
        self.tolerances = list(tolerances)
        self.min_confidence = min_confidence

    def error(self, camera: int, skeleton: np.ndarray, detection: np.ndarray) -> float:
        """The median distance (px) between ``detection`` and ``skeleton`` reprojected into ``camera``; inf
        with fewer than :data:`FEWEST_KEYPOINTS` keypoints in common."""
        common = np.isfinite(skeleton).all(axis=1) & (detection[:, 2] >= self.min_confidence)
        if common.sum() < FEWEST_KEYPOINTS:
            return float("inf")
        reprojected = self.cameras[camera].project(skeleton[common])
        return float(np.median(np.linalg.norm(reprojected - detection[common, :2], axis=1)))

    def skeleton(self, frame: Sequence[Detections], members: dict[int, int]) -> np.ndarray:
        """[L, 3] the members' detections triangulated, each keypoint weighted by its confidence."""
        used = sorted(members)
        detections = np.stack([frame[c][members[c]] for c in used])
        weights = np.where(detections[:, :, 2] >= self.min_confidence, detections[:, :, 2], 0.0)
        return triangulate([self.cameras[c] for c in used], detections[:, :, :2], weights)

    def persons(self, frame: Sequence[Detections]) -> list[tuple[dict[int, int], np.ndarray]]:
        """Every person two or more cameras agree on: (camera → its detection's index, [L, 3] skeleton),
        each detection in one person at most."""
        found: dict[frozenset, tuple[dict[int, int], np.ndarray, float]] = {}
        for a, b in combinations(range(len(frame)), 2):
            for i in range(len(frame[a])):
                for j in range(len(frame[b])):
                    pair = {a: i, b: j}
                    skeleton = self.skeleton(frame, pair)
                    if any(self.error(c, skeleton, frame[c][index]) > self.tolerances[c] for c, index in pair.items()):
                        continue
                    members = dict(pair)
                    for c in range(len(frame)):
                        if c in pair or not len(frame[c]):
                            continue
                        errors = [self.error(c, skeleton, detection) for detection in frame[c]]
                        if min(errors) <= self.tolerances[c]:
                            members[c] = int(np.argmin(errors))
                    key = frozenset(members.items())
                    if key not in found:
                        skeleton = self.skeleton(frame, members)
                        spread = float(np.mean([self.error(c, skeleton, frame[c][index]) / self.tolerances[c] for c, index in members.items()]))
                        found[key] = (members, skeleton, spread)
        persons, taken = [], set()
        for members, skeleton, _ in sorted(found.values(), key=lambda person: (-len(person[0]), person[2])):
            if taken.isdisjoint(members.items()):
                persons.append((members, skeleton))
                taken.update(members.items())
        return persons
