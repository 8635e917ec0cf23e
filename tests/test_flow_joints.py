"""Measuring flow against triangulated joints: exact flows at the joints' projections predict their next
positions where constant velocity and standing still cannot."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import zarr
from rig_fixtures import ring_cameras, write_blank_session

from mmcsplat.analysis.flow_joints import joint_prediction_errors
from mmcsplat.storage.landmark_formats import write_trc
from mmcsplat.storage.session.flow import FlowPair, FlowWriter
from mmcsplat.training.flow_lifting import camera_matrices, project

CAMERAS = ring_cameras(["a", "b", "c"], width=160, height=120, distortion=(0, 0, 0, 0, 0))
FRAMES = 5
START = np.array([[0.0, 0.0, 0.0], [0.3, 0.2, 0.1], [-0.3, 0.1, 0.2]])
ACCELERATION = np.array([0.004, -0.002, 0.003])  # metres per frame²


def positions(t: int) -> np.ndarray:
    return START + ACCELERATION * t**2


def write_joints(tmp_path, source: str):
    """The joints as a TRC file or as a synthetic capture's ground truth; returns the path to give."""
    names, trajectory = ["hip", "knee", "ankle"], np.stack([positions(t) for t in range(FRAMES)])
    if source == "trc":
        write_trc(tmp_path / "joints.trc", names, np.arange(FRAMES) / 30.0, trajectory, 30.0)
        return tmp_path / "joints.trc"
    truth = zarr.open_group(str(tmp_path / "capture" / "ground_truth.zarr"), mode="w")
    truth.create_array("joints", data=trajectory).attrs["joint_names"] = names
    return tmp_path / "capture"


@pytest.mark.parametrize("source", ["trc", "ground truth"])
def test_exact_flow_predicts_accelerating_joints(tmp_path, source):
    url = tmp_path / "s.zarr"
    write_blank_session(url, CAMERAS, FRAMES)
    K, viewmats = camera_matrices(CAMERAS)
    with FlowWriter(url, method={"name": "exact"}, cameras=[camera.name for camera in CAMERAS]) as writer:
        for t in range(FRAMES - 1):
            before, _, _ = project(torch.as_tensor(positions(t)), K, viewmats)
            after, _, _ = project(torch.as_tensor(positions(t + 1)), K, viewmats)
            for c, camera in enumerate(CAMERAS):
                forward = np.zeros((120, 160, 2), np.float32)
                for (u, v), shift in zip(before[c].numpy(), (after[c] - before[c]).numpy(), strict=True):
                    forward[int(v) - 3 : int(v) + 4, int(u) - 3 : int(u) + 4] = shift  # each joint's neighbourhood moves with it
                confidence = np.ones((120, 160), np.float32)
                writer.write(camera.name, t, FlowPair(forward, -forward, confidence, confidence))
    errors = joint_prediction_errors(url, write_joints(tmp_path, source))
    assert errors.names == ("hip", "knee", "ankle") and errors.frames.tolist() == [1, 2, 3]
    assert np.nanmax(errors.flow) < 1e-3  # float16 flow, exact otherwise
    np.testing.assert_allclose(errors.constant_velocity, 2 * np.linalg.norm(ACCELERATION), rtol=1e-6)
    assert (errors.still > 0.01).all()
    summary = errors.summary()
    assert summary["lifted_share"] == 1.0 and summary["moving_flow_median_mm"] < 1.0
