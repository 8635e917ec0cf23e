"""How well a session's optical flow, lifted to 3D, predicts where triangulated joints go next.

For each session frame t with both neighbours, each joint's position at t (from a TRC file, as Pose2Sim
writes it, or a synthetic capture's ground-truth joints) is projected into the training cameras with flow; the flow at those pixels, weighted by its
confidence (joints have no Gaussians, so no visibility), is lifted to a 3D displacement
(:func:`mmcsplat.training.flow_lifting.lift_flow`) and the prediction X_t + d compared with the joint at
t+1 — beside constant velocity (2 X_t − X_{t−1}) and standing still (X_t). It measures the motion evidence
flow-guided prediction starts each frame from, with no fit in between.
"""

from __future__ import annotations

import os

import attrs
import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.storage.ground_truth import GroundTruthReader
from mmcsplat.storage.landmark_formats import read_trc
from mmcsplat.storage.session import SessionReader
from mmcsplat.storage.session.flow import SessionFlow, pair_present
from mmcsplat.training.flow_lifting import camera_matrices, lift_flow, project, sample_field

PREDICTIONS = ("flow", "constant_velocity", "still")
#: A joint moving more than this between two frames counts as moving (TRC joints jitter by about 1 cm).
MOVING_M = 0.02


@attrs.frozen(eq=False)
class JointPredictionErrors:
    """Distances in metres [F, J] between each joint at frame t+1 and its prediction from frame t, for the
    frames ``frames`` [F] (t) and joints ``names``: by the lifted flow (NaN where it was not lifted), at
    constant velocity, and standing still."""

    names: tuple[str, ...]
    frames: np.ndarray
    flow: np.ndarray
    constant_velocity: np.ndarray
    still: np.ndarray

    def summary(self) -> dict[str, float]:
        """Median and 90th percentile in millimetres of each prediction, over all joints and over the moving
        ones (those standing still would miss by more than :data:`MOVING_M`), and the share of joints lifted."""
        figures = {}
        moving = self.still > MOVING_M
        for name in PREDICTIONS:
            for subset, selected in (("", np.ones_like(moving)), ("moving_", moving)):
                errors = getattr(self, name)[selected]
                errors = errors[np.isfinite(errors)]
                figures[f"{subset}{name}_median_mm"] = float(np.median(errors) * 1000)
                figures[f"{subset}{name}_p90_mm"] = float(np.percentile(errors, 90) * 1000)
        figures["moving_share"] = float(moving.mean())
        figures["lifted_share"] = float(np.isfinite(self.flow).mean())
        return figures


def read_joints(path: str | os.PathLike, convention: str = "pose2sim") -> tuple[tuple[str, ...], np.ndarray]:
    """Joint names and positions [T, J, 3] (metres, row k = capture frame k) of a TRC file, or of a synthetic
    capture's ground truth (the capture folder or its ``ground_truth.zarr``)."""
    if os.path.isdir(path):
        truth = GroundTruthReader(path)
        return tuple(truth.names("joints")), truth.points("joints")
    joints = read_trc(path, convention)
    return tuple(joints.names), joints.positions


def joint_prediction_errors(url: str | os.PathLike, joints: str | os.PathLike, convention: str = "pose2sim") -> JointPredictionErrors:
    """The prediction errors of the joints in ``joints`` (:func:`read_joints`) over the session at ``url``,
    whose flow must have been computed."""
    session, flow = SessionReader(url), SessionFlow(url)
    cameras = [session.camera(name) for name in session.train_cameras if flow.has(name)]
    if len(cameras) < 2:
        raise InputError(f"{session.url}: fewer than two training cameras have optical flow; run `mmcsplat flow {session.url}` first")
    names, all_positions = read_joints(joints, convention)
    rows = session.capture_frames(np.arange(session.num_frames))
    if rows.max() >= len(all_positions):
        raise InputError(f"{joints}: {len(all_positions)} frames of joints, but the session reaches capture frame {rows.max()}")
    positions = all_positions[rows]
    K, viewmats = camera_matrices(cameras)
    frames, errors = [], {name: [] for name in PREDICTIONS}
    for t in range(1, session.num_frames - 1):
        here = torch.as_tensor(positions[t])
        pixels, _, _ = project(here, K, viewmats)
        flows = torch.zeros(len(cameras), len(here), 2)
        weights = torch.zeros(len(cameras), len(here))
        for c, camera in enumerate(cameras):
            if pair_present(session.present(camera.name))[t]:
                pair = flow.pair(t, camera.name)
                flows[c] = sample_field(pair.forward, pixels[c])
                weights[c] = sample_field(pair.forward_confidence, pixels[c])[:, 0]
        motion = lift_flow(here, cameras, flows, weights)
        lifted = np.where(motion.lifted.numpy()[:, None], positions[t] + motion.displacement.double().numpy(), np.nan)
        truth = positions[t + 1]
        for name, predicted in (("flow", lifted), ("constant_velocity", 2 * positions[t] - positions[t - 1]), ("still", positions[t])):
            errors[name].append(np.linalg.norm(predicted - truth, axis=-1))
        frames.append(t)
    return JointPredictionErrors(names, np.asarray(frames), *(np.asarray(errors[name]) for name in PREDICTIONS))
