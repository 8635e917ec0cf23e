"""The rendered motion image and the flow loss (docs/dynamics.md, "Flow loss").

Each Gaussian's projected displacement since the previous frame, (du, dv) = π(μ) − π(μ_prev) in a view's
camera, is carried as two extra feature channels, so the renderer composites it like colour: the motion
image Σᵢ wᵢ (du, dv)ᵢ, differentiable with respect to the current means through both the displacement
and the footprints. It lies on the current frame's pixels, where the stored flow of the pair (t−1, t)
that describes the motion is the backward flow: negated, it is the observed motion since frame t−1 at
frame t's pixels, with the backward confidence. A render at 1/f of the flow's resolution (coarse to fine,
:mod:`.coarse_views`) is compared with the flow area-averaged over f × f blocks and divided by f.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from mmcsplat.plugin_api.interfaces import TrainingView
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras, RenderOutput
from mmcsplat.storage.session.flow import FlowPair

from .coarse_views import area_downsample

#: Feature channels the motion image adds after the Gaussians' own.
MOTION_CHANNELS = 2


def projected_displacement(previous_means: torch.Tensor, means: torch.Tensor, cameras: RenderCameras) -> torch.Tensor:
    """[N, 2] pixels moved by each Gaussian from ``previous_means`` (constant) to ``means`` [N, 3] in the one
    camera of ``cameras``; differentiable with respect to ``means``."""
    K, viewmat = cameras.K[0].to(means.dtype), cameras.viewmats[0].to(means.dtype)

    def pixels(points: torch.Tensor) -> torch.Tensor:
        homogeneous = (points @ viewmat[:3, :3].T + viewmat[:3, 3]) @ K.T
        return homogeneous[:, :2] / homogeneous[:, 2:3].clamp_min(1e-6)

    return pixels(means) - pixels(previous_means.detach())


def with_motion(gaussians: Gaussians, previous_means: torch.Tensor, cameras: RenderCameras) -> Gaussians:
    """``gaussians`` with their projected displacement in ``cameras`` appended as the last
    :data:`MOTION_CHANNELS` feature channels."""
    motion = projected_displacement(previous_means, gaussians.means, cameras).to(gaussians.features.dtype)
    return Gaussians(gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits, gaussians.colors,
                     torch.cat([gaussians.features, motion], dim=1))


def motion_image(render: RenderOutput) -> torch.Tensor:
    """[H, W, 2] the composited motion channels of a render of one camera, over no background."""
    return render.features[0, ..., -MOTION_CHANNELS:]


class FlowLoss:
    """A loss term (:data:`~mmcsplat.training.loop.LossTerm`): the confidence-weighted mean L1 distance, on the
    subject's pixels (the view's mask), between the rendered motion image and the observed motion since the
    previous frame. Where a pixel is partly covered the observed motion is scaled by the rendered alpha, as
    the composited channels are. :meth:`observe` sets each camera's flow for the frame being fitted; a view
    whose camera has none contributes nothing. A render smaller than the flow by an integer factor f
    (coarse to fine) is compared with the flow reduced to its size (module docstring)."""

    def __init__(self, weight: float) -> None:
        self.weight = weight
        self._observed: dict[tuple[str, int], tuple[torch.Tensor, torch.Tensor]] = {}

    def observe(self, pairs: Mapping[str, FlowPair]) -> None:
        """The flow pairs (t−1, t) of the frame t being fitted, by camera name."""
        self._observed = {(name, 1): (torch.from_numpy(-np.asarray(pair.backward, np.float32)),
                                 torch.from_numpy(np.asarray(pair.backward_confidence, np.float32)))
                          for name, pair in pairs.items()}

    def _at_size(self, camera: str, height: int) -> tuple[torch.Tensor, torch.Tensor] | None:
        """(motion [h, w, 2], confidence [h, w]) of ``camera`` for a render ``height`` rows high, or ``None``."""
        full = self._observed.get((camera, 1))
        if full is None:
            return None
        factor = full[0].shape[0] // height
        if (camera, factor) not in self._observed:
            motion, confidence = full
            self._observed[(camera, factor)] = (area_downsample(motion, factor) / factor, area_downsample(confidence, factor))
        return self._observed[(camera, factor)]

    def __call__(self, step: int, render: RenderOutput, view: TrainingView) -> torch.Tensor | None:
        observed = self._at_size(view.camera.name, render.alpha.shape[1])
        if observed is None:
            return None
        motion, confidence = observed
        weight = confidence if view.mask is None else confidence * view.mask
        total = weight.sum()
        if total <= 0:
            return None
        residual = (motion_image(render) - render.alpha[0, ..., None].detach() * motion).abs().sum(-1)
        return self.weight * (weight * residual).sum() / total
