"""The per-view objective every training shares: the image loss of a render against its view, plus the
segmentation loss weighted by λ_seg — the first-frame fit's, and each dynamics method's on later frames."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from . import losses

if TYPE_CHECKING:
    from mmcsplat.plugin_api.interfaces import TrainingView
    from mmcsplat.plugin_api.render_contract import RenderOutput

    from .model import GaussianModel
    from .settings import FitSettings


def view_loss(
    model: GaussianModel, view: TrainingView, render: RenderOutput, settings: FitSettings, lambda_seg: float | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, image) of ``render`` — ``view``'s camera alone — against ``view``: image is the render over
    the view's backdrop after the camera's colour correction; loss is λ_image · L_im(image) + λ_seg · L_seg,
    each (1 − w)·L1 + w·D-SSIM with w = ``settings.ssim_weight``. ``lambda_seg`` overrides the settings'."""
    image = model.correct_color(view.composite(render), view.index)
    loss = settings.lambda_image * losses.photometric_loss(image, view.image, settings.ssim_weight)
    lambda_seg = settings.lambda_seg if lambda_seg is None else lambda_seg
    if lambda_seg > 0:
        loss = loss + lambda_seg * losses.photometric_loss(render.features[0, ..., :1], view.seg_target, settings.ssim_weight)
    return loss, image


def view_psnr(image: torch.Tensor, view: TrainingView) -> float:
    """PSNR (dB) of a rendered ``image`` against its view's target, for progress and records."""
    return float(losses.psnr(image.detach().clamp(0, 1), view.image))
