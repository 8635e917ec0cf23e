"""The joints of a capture written by ``mmcsplat synth``: its ``ground_truth.zarr`` (docs/synthetic.md)
holds ``joints`` [T, J, 3] in world metres with their ``joint_names``, at the capture's frames.

Their projections into the session's cameras are the capture's 2D keypoints: the detector of a synthetic
capture, exact and blind to occlusion, so keypoint guidance and the 2D error run on it as on a real one."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import ClassVar

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError, MissingFileError
from mmcsplat.plugin_api.interfaces import KeypointObservations, Landmarks, LandmarkSource
from mmcsplat.plugin_api.parameters import parameter
from mmcsplat.storage.ground_truth import GROUND_TRUTH, GroundTruthReader
from mmcsplat.storage.session import SessionReader


@attrs.frozen
class SyntheticJoints(LandmarkSource):
    """The synthetic infant's 14 joints (waist, neck, shoulders, elbows, wrists, hips, knees, ankles)."""

    exact: ClassVar[bool] = True
    path: str | None = parameter(None, doc="the capture's ground_truth.zarr (default: beside the session's source capture)")

    def _path(self, session: SessionReader) -> Path:
        if self.path is not None:
            return Path(self.path)
        if not session.source:
            raise InputError(f"session {session.url} records no source capture: give the ground truth with path=…/ground_truth.zarr")
        return Path(session.source) / GROUND_TRUTH

    def read(self, session: SessionReader, frames: Sequence[int]) -> Landmarks:
        """The joints at session ``frames`` (through the capture's frame numbers: ingest may have subsampled)."""
        path = self._path(session)
        if not path.exists():
            raise MissingFileError(f"synthetic joints: {path} does not exist (a synthetic capture's ground truth)")
        truth = GroundTruthReader(path)
        truth.require_truth_of(session)
        positions = truth.points("joints", session.capture_frames(frames), "the session needs capture frame")
        return Landmarks(tuple(truth.names("joints")), frames, positions, source=f"synthetic joints {path}")

    def observations(self, session: SessionReader, frames: Sequence[int]) -> list[KeypointObservations]:
        """The joints projected into every camera of the session, confidence 1 where a joint is known, in front
        of the camera and inside its image, 0 elsewhere."""
        joints = self.read(session, frames)
        points = joints.positions.reshape(-1, 3)
        known = np.isfinite(points).all(axis=1)
        result = []
        for name in session.camera_names:
            camera = session.camera(name)
            pixels = np.zeros((len(points), 2))
            pixels[known] = camera.project(points[known])
            depth = np.full(len(points), -1.0)
            depth[known] = points[known] @ camera.R[2] + camera.t[2]
            seen = known & (depth > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < camera.width) \
                & (pixels[:, 1] >= 0) & (pixels[:, 1] < camera.height)
            shape = joints.positions.shape[:2]
            result.append(KeypointObservations(name, joints.names, frames, pixels.reshape(*shape, 2), seen.reshape(shape).astype(float)))
        return result
