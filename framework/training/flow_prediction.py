"""Predicting a frame's Gaussians from the session's optical flow (docs/dynamics.md, "Flow-guided prediction").

Each Gaussian's displacement from frame t to t+1 is lifted to 3D (:mod:`.flow_lifting`) from the forward
flow of pair t at its projection in each training camera with flow, weighted by the flow's confidence there
and by the Gaussian's visibility in that camera, so that an occluded Gaussian does not take its occluder's
motion. Visibility is the Gaussian's share of what it would draw unoccluded: its rendered contribution
Σₚ wᵢ(p) (the gradient of a rendered all-ones feature channel with respect to its own feature value, since a
feature composites as Σᵢ wᵢ fᵢ) over the integral of its 2D footprint, opacity · 2π √det Σ₂D.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import torch

from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.render_contract import LOW_PASS, Gaussians, RenderCameras
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.quaternions import quat_to_rotmat
from mmcsplat.storage.session.flow import SessionFlow

from .flow_lifting import LiftedMotion, camera_matrices, lift_flow, project, sample_field


def visibility(renderer: Renderer, gaussians: Gaussians, camera: Camera) -> torch.Tensor:
    """[N] in [0, 1]: how much of each Gaussian ``camera`` sees (module docstring); 0 for culled ones."""
    ones = torch.ones(gaussians.count, 1, requires_grad=True)
    probe = Gaussians(*(value.detach() for value in (gaussians.means, gaussians.quats, gaussians.log_scales,
                                                     gaussians.opacity_logits, gaussians.colors)), ones)
    render = renderer.render(probe, RenderCameras.from_cameras([camera]))
    (contribution,) = torch.autograd.grad(render.features[..., 0].sum(), ones)
    K, viewmats = camera_matrices([camera])
    _, _, jacobian = project(probe.means.to(torch.float64), K, viewmats)
    rotation = quat_to_rotmat(probe.quats.to(torch.float64))
    scales = torch.exp(probe.log_scales.to(torch.float64))
    covariance = rotation @ torch.diag_embed(scales**2) @ rotation.transpose(-1, -2)
    screen = jacobian[0] @ covariance @ jacobian[0].transpose(-1, -2) + LOW_PASS * torch.eye(2, dtype=torch.float64)
    footprint = torch.sigmoid(probe.opacity_logits.to(torch.float64)) * 2 * math.pi * torch.linalg.det(screen).clamp_min(0).sqrt()
    share = contribution[:, 0].to(torch.float64) / footprint.clamp_min(1e-12)
    return torch.where(render.visible[0], share.clamp(0, 1), 0.0).to(torch.float32)


class FlowPrediction:
    """The displacements of Gaussians between consecutive session frames, from a session's flow in the
    training ``cameras`` that have it."""

    def __init__(self, flow: SessionFlow, cameras: Sequence[Camera], renderer: Renderer) -> None:
        self.flow = flow
        self.cameras = tuple(camera for camera in cameras if flow.has(camera.name))
        self.renderer = renderer

    @classmethod
    def of_session(cls, url: str | os.PathLike, cameras: Sequence[Camera], renderer: Renderer) -> FlowPrediction | None:
        """The prediction from the session's flow, or ``None`` when fewer than two of ``cameras`` have flow."""
        flow = SessionFlow(url)
        prediction = cls(flow, cameras, renderer)
        return prediction if len(prediction.cameras) >= 2 else None

    def displacements(self, gaussians: Gaussians, t: int, subset: torch.Tensor | None = None) -> LiftedMotion:
        """The displacement from session frame ``t`` (where ``gaussians`` are) to ``t + 1`` of the Gaussians
        at the indices ``subset`` (default: all), with all of them occluding; those not lifted (seen by fewer
        than two cameras with flow of that pair, or ill-conditioned) are marked in ``lifted``."""
        subset = torch.arange(gaussians.count) if subset is None else subset
        means = gaussians.means.detach()[subset]
        flows = torch.zeros(len(self.cameras), len(subset), 2)
        weights = torch.zeros(len(self.cameras), len(subset))
        K, viewmats = camera_matrices(self.cameras)
        pixels, _, _ = project(means.to(torch.float64), K, viewmats)
        for c, camera in enumerate(self.cameras):
            if t + 1 >= self.flow.num_frames or not (self.flow.present(camera.name)[t] and self.flow.present(camera.name)[t + 1]):
                continue
            pair = self.flow.pair(t, camera.name)
            flows[c] = sample_field(pair.forward, pixels[c])
            weights[c] = sample_field(pair.forward_confidence, pixels[c])[:, 0] * visibility(self.renderer, gaussians, camera)[subset]
        return lift_flow(means, self.cameras, flows, weights)


class FlowGuidance:
    """A frame-to-frame prediction that moves the ``foreground`` Gaussians [N] bool by the lifted flow times
    ``gain`` and everything else — the background, and foreground Gaussians the flow does not lift — at
    constant velocity. ``fallbacks`` lists, per predicted frame, the foreground Gaussians left at constant
    velocity."""

    def __init__(self, prediction: FlowPrediction, foreground: torch.Tensor, gain: float = 1.0) -> None:
        self.prediction = prediction
        self.foreground = torch.as_tensor(foreground).nonzero()[:, 0]
        self.gain = gain
        self.fallbacks: list[int] = []

    def predict(self, gaussians: Gaussians, previous_means: torch.Tensor, t: int) -> torch.Tensor:
        """[N, 3] predicted means of session frame ``t + 1`` from ``gaussians`` at frame ``t`` and their means
        ``previous_means`` at the frame before."""
        means = gaussians.means.detach()
        predicted = 2 * means - previous_means
        motion = self.prediction.displacements(gaussians, t, self.foreground)
        lifted = self.foreground[motion.lifted]
        predicted[lifted] = means[lifted] + self.gain * motion.displacement[motion.lifted].to(means.dtype)
        self.fallbacks.append(motion.fallbacks)
        return predicted
