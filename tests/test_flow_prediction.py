"""Flow-guided prediction: the visibility that weights each camera's flow, and displacements read from a
session's stored flow."""

from __future__ import annotations

import math

import numpy as np
import torch
from rig_fixtures import ring_cameras, write_blank_session

from mmcsplat.backends.torch_reference import TorchReferenceRenderer
from mmcsplat.plugin_api.render_contract import Gaussians
from mmcsplat.storage.session.flow import FlowPair, FlowWriter
from mmcsplat.training.flow_lifting import camera_matrices, project
from mmcsplat.training.flow_prediction import FlowGuidance, FlowPrediction, visibility

CAMERAS = ring_cameras(["a", "b", "c"], width=96, height=72, distortion=(0, 0, 0, 0, 0))


def blobs(means, scales, opacities) -> Gaussians:
    count = len(means)
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(count, 1)
    return Gaussians.from_linear(torch.tensor(means, dtype=torch.float32), quats, torch.tensor(scales, dtype=torch.float32).repeat(1, 3),
                                 torch.tensor(opacities, dtype=torch.float32), torch.full((count, 3), 0.5))


def test_a_gaussian_behind_an_opaque_one_is_not_visible():
    camera = CAMERAS[0]
    towards = camera.center / np.linalg.norm(camera.center)
    front = (0.4 * towards).tolist()  # between the camera and the origin
    gaussians = blobs([[0.0, 0.0, 0.0], front, [0.0, 0.0, 0.3]], [[0.01], [0.06], [0.01]], [0.9, 0.99, 0.9])
    seen = visibility(TorchReferenceRenderer(), gaussians, camera)
    assert seen[0] < 0.1  # hidden behind the large opaque one (a few per cent through its edge)
    assert seen[1] > 0.8 and seen[2] > 0.8  # in full view
    far_side = visibility(TorchReferenceRenderer(), gaussians, CAMERAS[1])
    assert far_side[0] > 0.8


def test_a_gaussian_outside_the_image_is_not_visible():
    gaussians = blobs([[0.0, 0.0, 0.0], [50.0, 0.0, 0.0]], [[0.02], [0.02]], [0.9, 0.9])
    assert visibility(TorchReferenceRenderer(), gaussians, CAMERAS[0])[1] == 0


def test_displacements_from_stored_flow(tmp_path):
    """Flow fields made from a known 3D shift of a small blob, stored in a session, lift back to the shift."""
    url = tmp_path / "s.zarr"
    write_blank_session(url, CAMERAS, 2)
    shift = torch.tensor([0.02, -0.01, 0.015], dtype=torch.float64)
    centre = torch.zeros(1, 3, dtype=torch.float64)
    K, viewmats = camera_matrices(CAMERAS)
    before, _, _ = project(centre, K, viewmats)
    after, _, _ = project(centre + shift, K, viewmats)
    with FlowWriter(url, method={"name": "test"}, cameras=[camera.name for camera in CAMERAS]) as writer:
        for c, camera in enumerate(CAMERAS):
            forward = np.broadcast_to((after[c, 0] - before[c, 0]).numpy().astype(np.float32), (72, 96, 2)).copy()
            confidence = np.ones((72, 96), np.float32)
            writer.write(camera.name, 0, FlowPair(forward, -forward, confidence, confidence))
    prediction = FlowPrediction.of_session(url, CAMERAS, TorchReferenceRenderer())
    assert prediction is not None and len(prediction.cameras) == 3
    motion = prediction.displacements(blobs([[0.0, 0.0, 0.0]], [[0.02]], [0.9]), 0)
    assert motion.lifted.all()
    # the flow is stored as float16: a few thousandths of a pixel, well under a millimetre here
    assert float((motion.displacement[0].double() - shift).norm()) < 1e-3
    assert not math.isnan(float(motion.displacement.sum()))
    # The prediction moves a foreground Gaussian by the lifted shift times the gain (run's compensates DIS's shortfall).
    gaussians = blobs([[0.0, 0.0, 0.0]], [[0.02]], [0.9])
    for gain in (1.0, 2.0):
        predicted = FlowGuidance(prediction, torch.tensor([True]), gain).predict(gaussians, gaussians.means.detach(), 0)
        assert float((predicted[0].double() - gain * shift).norm()) < 2e-3
