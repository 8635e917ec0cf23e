"""Landmarks from 2D keypoints detected in several calibrated cameras: the detections are mapped into the
session's stored (undistorted, rescaled) images and triangulated — what the ``openpose``,
``deeplabcut`` and ``sleap`` sources share.

Pixels: a keypoint at (x, y) of the source video is mapped into the stored image through the camera as
recorded (its distortion and decoded size, kept in the session's provenance by ingest) and the stored,
undistorted camera: the recorded lens undone (:meth:`Camera.undistort`) with the stored K as the new projection.

Triangulation (:func:`mmcsplat.scene.triangulation.triangulate`): for each frame and keypoint, the linear
(DLT) solution over the cameras whose detection has a confidence above the source's threshold, each row
weighted by its confidence; at least two cameras are needed, else the landmark is unknown (NaN) at that
frame.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence

import numpy as np

from mmcsplat.plugin_api.interfaces import Landmarks, LandmarkSource
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.triangulation import triangulate
from mmcsplat.storage.session import SessionReader

#: The confidence of a keypoint from a tool that stores none, only whether it detected it (FreeMoCap, Caliscope).
DETECTED = 1.0


def to_session_pixels(points: np.ndarray, recorded: Camera, stored: Camera) -> np.ndarray:
    """[..., 2] pixels of the recorded (distorted) camera → the stored (undistorted) camera's pixels."""
    return recorded.undistort(points, stored.K)


def detected_people(found: np.ndarray) -> np.ndarray:
    """[P', L, 3] the people (or animals) of ``found`` [P, L, 3] (x, y, confidence; NaN where undetected) with any keypoint
    detected, undetected keypoints zero (confidence 0)."""
    known = np.all(np.isfinite(found), axis=-1)
    return np.where(known[..., None], found, 0.0)[known.any(axis=1)]


def people_to_session_pixels(people: Sequence[np.ndarray], recorded: Camera | None, stored: Camera) -> list[np.ndarray]:
    """Each frame's people [P, L, 3] (x, y, confidence) with their pixels mapped by :func:`to_session_pixels`,
    every frame's in one call (undoing a lens iterates per point, not per call); unchanged where the session
    keeps no camera as recorded (``recorded`` None: a session ingested before mmcsplat kept them)."""
    if recorded is None:
        return list(people)
    stacked = np.concatenate(people)
    stacked[..., :2] = to_session_pixels(stacked[..., :2], recorded, stored)
    return np.split(stacked, np.cumsum([len(frame) for frame in people])[:-1])


class TriangulatedKeypoints(LandmarkSource):
    """A keypoint source: :meth:`observations` per camera (its subclass reads the files); the landmarks
    are their triangulation."""

    @property
    @abstractmethod
    def described(self) -> str:
        """What the keypoints are, for the landmarks' ``source``."""

    def read(self, session: SessionReader, frames: Sequence[int]) -> Landmarks:
        """The keypoints triangulated at every session frame (NaN where fewer than two cameras saw one)."""
        observed = self.observations(session, frames)
        names = observed[0].names
        cameras = [session.camera(o.camera) for o in observed]
        pixels = np.stack([o.pixels for o in observed])  # [C, T, L, 2]
        weights = np.stack([o.confidence for o in observed])
        positions = np.stack([triangulate(cameras, pixels[:, k], weights[:, k]) for k in range(len(frames))])
        return Landmarks(names, frames, positions, source=f"{self.described}, triangulated")
