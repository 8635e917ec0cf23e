"""The rendered motion image: each Gaussian's projected displacement composited like colour, and the flow
loss that compares it with the observed flow."""

from __future__ import annotations

import numpy as np
import torch
from rig_fixtures import ring_cameras

from mmcsplat.backends.torch_reference import TorchReferenceRenderer
from mmcsplat.plugin_api.interfaces import TrainingView
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras
from mmcsplat.storage.session.flow import FlowPair
from mmcsplat.training.flow_lifting import camera_matrices, project
from mmcsplat.training.motion_image import FlowLoss, motion_image, with_motion

CAMERA = ring_cameras(["a"], width=96, height=72, distortion=(0, 0, 0, 0, 0))[0]
CAMERAS = RenderCameras.from_cameras([CAMERA])
PREVIOUS = torch.tensor([[0.0, 0.0, 0.0], [0.25, -0.2, 0.1], [-0.2, 0.25, 0.2]])
SHIFT = torch.tensor([[0.08, -0.04, 0.06], [-0.1, 0.0, 0.04], [0.0, 0.09, -0.08]])


def blobs(means: torch.Tensor) -> Gaussians:
    count = len(means)
    return Gaussians.from_linear(means, torch.tensor([[1.0, 0, 0, 0]]).repeat(count, 1), torch.full((count, 3), 0.04),
                                 torch.full((count,), 0.9), torch.full((count, 3), 0.5), torch.zeros(count, 1))


def render_motion(means: torch.Tensor):
    return TorchReferenceRenderer().render(with_motion(blobs(means), PREVIOUS, CAMERAS), CAMERAS)


def test_rendered_motion_equals_the_projection_difference_at_each_centre():
    means = PREVIOUS + SHIFT
    render = render_motion(means)
    assert render.features.shape[-1] == 1 + 2  # the segmentation channel, then (du, dv)
    K, viewmats = camera_matrices([CAMERA])
    before, _, _ = project(PREVIOUS.double(), K, viewmats)
    after, _, _ = project(means.double(), K, viewmats)
    expected = (after - before)[0]
    for centre, displacement in zip(after[0], expected, strict=True):
        u, v = (int(round(float(x))) for x in centre)
        rendered = motion_image(render)[v, u] / render.alpha[0, v, u]  # composited: alpha-weighted
        assert float(displacement.norm()) > 1.0  # a real motion of several pixels
        np.testing.assert_allclose(rendered.detach().numpy(), displacement.numpy(), atol=0.02)


def test_motion_image_is_differentiable_in_the_current_means():
    """The gradient of the rendered motion at a Gaussian's centre matches a finite difference of its mean."""
    means = (PREVIOUS + SHIFT).clone().requires_grad_(True)
    K, viewmats = camera_matrices([CAMERA])
    u, v = (int(round(float(x))) for x in project(means.detach()[:1].double(), K, viewmats)[0][0, 0])
    (gradient,) = torch.autograd.grad(motion_image(render_motion(means))[v, u, 0], means)
    step = 1e-4
    for axis in range(3):
        offset = torch.zeros_like(means)
        offset[0, axis] = step
        ahead = motion_image(render_motion(means.detach() + offset))[v, u, 0]
        behind = motion_image(render_motion(means.detach() - offset))[v, u, 0]
        np.testing.assert_allclose(float(gradient[0, axis]), float((ahead - behind) / (2 * step)), rtol=0.01, atol=0.1)
    assert float(gradient[0].abs().max()) > 10.0  # pixels per metre: the motion channel does respond


def view_with_mask(mask: torch.Tensor) -> TrainingView:
    return TrainingView(CAMERA, 0, torch.zeros(72, 96, 3), mask, mask[..., None].float(), torch.zeros(3))


def observed(field: np.ndarray) -> dict[str, FlowPair]:
    confidence = np.ones((72, 96), np.float32)
    return {CAMERA.name: FlowPair(-field, field, confidence, confidence)}  # forward is unused: the backward flow counts


def test_flow_loss_vanishes_on_the_true_motion_and_grows_away_from_it():
    """One Gaussian moved by a uniform observed flow: the loss is nil at its true projected motion."""
    means = PREVIOUS[:1] + SHIFT[:1]
    K, viewmats = camera_matrices([CAMERA])
    true = (project(means.double(), K, viewmats)[0] - project(PREVIOUS[:1].double(), K, viewmats)[0])[0, 0].float().numpy()
    render = TorchReferenceRenderer().render(with_motion(blobs(means), PREVIOUS[:1], CAMERAS), CAMERAS)
    view = view_with_mask(render.alpha[0].detach() > 0.3)  # the subject's pixels: the Gaussian's footprint
    loss = FlowLoss(2.0)
    loss.observe(observed(np.broadcast_to(-true, (72, 96, 2)).astype(np.float32)))
    assert float(loss(0, render, view)) < 1e-3
    loss.observe(observed(np.broadcast_to(-true - [3.0, 0.0], (72, 96, 2)).astype(np.float32)))
    wrong = float(loss(0, render, view))
    assert wrong > 2.0 * 3.0 * 0.3  # a 3 px error, weighted, where alpha > 0.3
    assert FlowLoss(2.0)(0, render, view) is None  # no flow observed for the camera: no term
