"""Keypoint guidance (docs/dynamics.md, "Keypoint guidance"): an optional loss term pulling the Gaussians
that carry each 2D keypoint towards where the training cameras detected it.

Binding: the keypoints of the first tracked frame are triangulated from the training cameras' detections
alone (:func:`~mmcsplat.scene.triangulation.triangulate`) and bound to the subject's Gaussians there as
landmarks are (:func:`~mmcsplat.scene.landmark_anchors.bind_landmarks`: the 8 nearest within 10 cm,
anchored in their local frames). Triangulated rather than read from a 3D file: every keypoint source has
them, an infant's capture has no marker file, and a held-out camera's detections stay out.

Loss, for a view of training camera c at frame t: the confidence-weighted mean over the bound keypoints
detected there (confidence > 0: each source zeroes those below its ``min_confidence``) of the Huber
penalty of the distance, in the stored image's pixels, between the projection of the keypoint's carried
position (its anchors' weighted proposals, differentiable in their means and rotations) and the detection:
d²/(2δ) within δ pixels, d − δ/2 beyond, so a wrong detection pulls no harder than a few pixels' worth.
A held-out camera's detections never enter: only the training cameras' are kept. Nor does a detection the
other training cameras contradict: at each frame the keypoints are triangulated from all training
cameras' detections, and a detection whose reprojection misses it by more than :data:`MAX_DISAGREEMENT` of
its image's diagonal is left out. Pulled towards two detections no 3D point explains (OpenPose's nose
seen by only two cameras of the Pose2Sim demo misses its triangulation by 14–22 px in some frames, where
every detection's 99th percentile is 9 px), the anchors settle at a point neither camera shows.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import KeypointObservations, TrainingView
from mmcsplat.plugin_api.render_contract import RenderOutput
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.landmark_anchors import MAX_DISTANCE, LandmarkBinding, bind_landmarks, proposals, subject_gaussians
from mmcsplat.scene.triangulation import triangulate

from .flow_lifting import camera_matrices, project
from .loop import LossTerm

#: A detection farther than this share of its image's diagonal from the reprojection of the keypoint
#: triangulated from every training camera's detections is inconsistent with them (1/4-scale Pose2Sim: 11 px).
MAX_DISAGREEMENT = 0.02


def huber(distance_squared: torch.Tensor, delta: float) -> torch.Tensor:
    """The Huber penalty of distances given squared: d²/(2δ) below δ, d − δ/2 above (its gradient finite at 0)."""
    linear = torch.sqrt(distance_squared.clamp_min(delta**2)) - delta / 2
    return torch.where(distance_squared < delta**2, distance_squared / (2 * delta), linear)


def consistent_detections(cameras: Sequence[Camera], observations: Sequence[KeypointObservations]) -> dict[str, np.ndarray]:
    """Per camera, [F, K] bool: whether each detection of ``observations`` (one per camera of ``cameras``,
    the same frames and keypoints) agrees with the others — within :data:`MAX_DISAGREEMENT` of its image's
    diagonal of the reprojection of the keypoint triangulated from all of them at that frame. A keypoint
    detected in fewer than two cameras has nothing to disagree with and is kept."""
    K, viewmats = camera_matrices(cameras)
    tolerance = np.array([MAX_DISAGREEMENT * np.hypot(camera.width, camera.height) for camera in cameras])
    pixels = np.stack([o.pixels for o in observations])  # [C, F, K, 2]
    confidence = np.stack([o.confidence for o in observations])
    consistent = np.ones(confidence.shape, dtype=bool)
    for k in range(pixels.shape[1]):
        reprojected = project(torch.as_tensor(triangulate(cameras, pixels[:, k], confidence[:, k])), K, viewmats)[0].numpy()
        error = np.linalg.norm(reprojected - pixels[:, k], axis=-1)
        consistent[:, k] = ~(error > tolerance[:, None])  # NaN (not triangulated, or not detected) is kept
    return {o.camera: consistent[c] for c, o in enumerate(observations)}


class KeypointGuidance:
    """The guidance (module docstring) of the keypoints ``binding`` binds, detected as ``observations`` (in
    ``binding.names`` order) at session ``frames`` in the training ``cameras``: :meth:`term` is its loss term,
    :meth:`observe` sets the frame being fitted. Build it with :meth:`bind`."""

    def __init__(self, binding: LandmarkBinding, cameras: Sequence[Camera], observations: Sequence[KeypointObservations],
                 frames: Sequence[int], weight: float, huber_px: float) -> None:
        self.binding = binding
        self.weight = weight
        self.huber_px = huber_px
        self._cameras = {camera.name: camera for camera in cameras}
        self._frames = {int(frame): k for k, frame in enumerate(frames)}
        self._observed = {o.camera: o for o in observations if o.camera in self._cameras}
        self._consistent = consistent_detections([self._cameras[name] for name in self._observed], list(self._observed.values()))
        self._weights = torch.as_tensor(binding.weights)
        self._frame: int | None = None

    @classmethod
    def bind(cls, observations: Sequence[KeypointObservations], cameras: Sequence[Camera], frames: Sequence[int],
             params: Mapping[str, torch.Tensor], foreground: np.ndarray, weight: float, huber_px: float) -> KeypointGuidance:
        """Triangulate the keypoints at ``frames[0]`` from the detections of the training ``cameras`` alone and
        bind them to the subject's Gaussians (``foreground`` indices) of ``params`` there; an error when no
        keypoint can be bound."""
        names = {camera.name for camera in cameras}
        training = [o for o in observations if o.camera in names]
        if len(training) < 2:
            raise InputError(f"keypoint guidance needs detections in two training cameras at least, found them in "
                             f"{[o.camera for o in training] or 'none'} of {sorted(names)}: check the keypoint source's folder")
        keypoints = training[0].names
        for o in training:
            if o.names != keypoints:
                raise InputError(f"keypoints of camera {o.camera!r} are {list(o.names)}, those of {training[0].camera!r} {list(keypoints)}: "
                                 "one keypoint model for every camera")
        by_name = {camera.name: camera for camera in cameras}
        positions = triangulate([by_name[o.camera] for o in training], np.stack([o.pixels[0] for o in training]),
                                np.stack([o.confidence[0] for o in training]))
        binding = bind_landmarks(keypoints, positions, params["means"].detach().double().numpy(), params["quats"].detach().double().numpy(),
                                 subject_gaussians(params, foreground))
        if not binding.bound.any():
            raise InputError(f"keypoint guidance: no keypoint triangulated from the training cameras {sorted(names)} at frame {frames[0]} "
                             f"lies within {MAX_DISTANCE * 100:.0f} cm of the subject's Gaussians: check the keypoints' folder belongs to this session")
        return cls(binding, cameras, training, frames, weight, huber_px)

    def observe(self, frame: int) -> None:
        """Guide towards the detections at session ``frame`` (none where the keypoints do not cover it)."""
        self._frame = self._frames.get(int(frame))

    def positions(self, means: torch.Tensor, quats: torch.Tensor) -> torch.Tensor:
        """[L, 3] the keypoints' carried positions (zeros for unbound ones), differentiable."""
        return torch.einsum("lk,lki->li", self._weights.to(means.dtype), proposals(self.binding, means, quats))

    def loss(self, camera: str, means: torch.Tensor, quats: torch.Tensor) -> torch.Tensor | None:
        """The weighted loss in ``camera`` at the observed frame, or ``None`` without a detection to pull towards."""
        observed = self._observed.get(camera)
        if observed is None or self._frame is None:
            return None
        confidence = torch.tensor(observed.confidence[self._frame], dtype=means.dtype)
        target = torch.tensor(observed.pixels[self._frame], dtype=means.dtype)
        K, viewmats = camera_matrices([self._cameras[camera]])
        pixels, depth, _ = project(self.positions(means, quats), K.to(means.dtype), viewmats.to(means.dtype))
        used = (torch.as_tensor(self.binding.bound) & (confidence > 0) & torch.isfinite(target).all(-1) & (depth[0] > 0)
                & torch.as_tensor(self._consistent[camera][self._frame]))
        if not used.any():
            return None
        penalty = huber(((pixels[0][used] - target[used]) ** 2).sum(-1), self.huber_px)
        return self.weight * (confidence[used] * penalty).sum() / confidence[used].sum()

    def term(self, params: Mapping[str, torch.Tensor]) -> LossTerm:
        """The loss term of the trained Gaussian parameters ``params`` (their current ``means`` and ``quats`` at each step)."""
        def keypoints(step: int, render: RenderOutput, view: TrainingView) -> torch.Tensor | None:
            return self.loss(view.camera.name, params["means"], params["quats"])
        return keypoints

    def summary(self) -> dict[str, Any]:
        """What ``track.json`` records of the guidance."""
        return {"weight": self.weight, "huber_px": self.huber_px, "cameras": sorted(self._observed),
                "inconsistent_detections": {camera: int((~self._consistent[camera] & (o.confidence > 0)).sum())
                                            for camera, o in sorted(self._observed.items())},
                "keypoints": [name for name, ok in zip(self.binding.names, self.binding.bound, strict=True) if ok],
                "unbound": self.binding.unbound}
