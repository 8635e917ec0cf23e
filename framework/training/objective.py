"""The per-view objective every training shares: the image loss of a render against its view, plus the
segmentation loss weighted by λ_seg — the first-frame fit's, and each dynamics method's on later frames."""

from __future__ import annotations

import weakref
from typing import TYPE_CHECKING

import torch

from . import losses

if TYPE_CHECKING:
    from mmcsplat.plugin_api.interfaces import TrainingView
    from mmcsplat.plugin_api.render_contract import RenderOutput

    from .model import GaussianModel
    from .settings import FitSettings


#: The changed window's largest share of the image for which the windowed loss is used (beyond it, the
#: whole image costs about the same).
WINDOW_SHARE = 0.6


def view_loss(
    model: GaussianModel, view: TrainingView, render: RenderOutput, settings: FitSettings, lambda_seg: float | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, image) of ``render`` — ``view``'s camera alone — against ``view``: image is the render over
    the view's backdrop after the camera's colour correction; loss is λ_image · L_im(image) + λ_seg · L_seg,
    each (1 − w)·L1 + w·D-SSIM with w = ``settings.ssim_weight``. ``lambda_seg`` overrides the settings'.

    While the colour correction is frozen (tracking), the losses are computed over the window the Gaussians
    cover and the backdrop's share is added from a per-view table (:func:`~mmcsplat.training.losses.windowed_photometric_loss`):
    the same value and gradients, at the cost of the subject's part of the image."""
    image = model.correct_color(view.composite(render), view.index)
    lambda_seg = settings.lambda_seg if lambda_seg is None else lambda_seg
    seg = render.features[0, ..., :1]
    window = None if model.camera_scale.requires_grad or model.camera_offset.requires_grad else changed_window(render.alpha[0])
    if window is None:
        loss = settings.lambda_image * losses.photometric_loss(image, view.image, settings.ssim_weight)
        if lambda_seg > 0:
            loss = loss + lambda_seg * losses.photometric_loss(seg, view.seg_target, settings.ssim_weight)
        return loss, image
    static_image, static_seg = _static_terms(model, view)
    loss = settings.lambda_image * losses.windowed_photometric_loss(image, view.image, static_image, *window, settings.ssim_weight)
    if lambda_seg > 0:
        loss = loss + lambda_seg * losses.windowed_photometric_loss(seg, view.seg_target, static_seg, *window, settings.ssim_weight)
    return loss, image


def changed_window(alpha: torch.Tensor) -> tuple[slice, slice] | None:
    """(rows, columns) of the box around the pixels of ``alpha`` [H, W] that any Gaussian reaches, widened by
    the SSIM's reach and clipped; ``None`` when no pixel is reached or the box covers most of the image."""
    rows = torch.nonzero(alpha.detach().amax(dim=1) > 0)[:, 0]
    if not len(rows):
        return None
    columns = torch.nonzero(alpha.detach().amax(dim=0) > 0)[:, 0]
    height, width = alpha.shape
    window = losses.widened(slice(int(rows[0]), int(rows[-1]) + 1), slice(int(columns[0]), int(columns[-1]) + 1), losses.SSIM_REACH, height, width)
    share = (window[0].stop - window[0].start) * (window[1].stop - window[1].start) / (height * width)
    return window if share <= WINDOW_SHARE else None


_STATIC: weakref.WeakKeyDictionary[TrainingView, tuple[torch.Tensor, losses.StaticPhotometric, losses.StaticPhotometric | None]] = (
    weakref.WeakKeyDictionary())


def _static_terms(model: GaussianModel, view: TrainingView) -> tuple[losses.StaticPhotometric, losses.StaticPhotometric | None]:
    """The view's backdrop alone (after the camera's colour correction) against its image, and nothing against
    its segmentation target, made once per view and colour correction."""
    with torch.no_grad():
        colour = torch.cat([model.camera_scale[view.index], model.camera_offset[view.index]])
        kept = _STATIC.get(view)
        if kept is not None and torch.equal(kept[0], colour):
            return kept[1], kept[2]
        backdrop = model.correct_color(torch.broadcast_to(view.backdrop, view.image.shape), view.index)
        image = losses.StaticPhotometric.of(backdrop, view.image)
        seg = None if view.seg_target is None else losses.StaticPhotometric.of(torch.zeros_like(view.seg_target), view.seg_target)
    _STATIC[view] = (colour, image, seg)
    return image, seg


def view_psnr(image: torch.Tensor, view: TrainingView) -> float:
    """PSNR (dB) of a rendered ``image`` against its view's target, for progress and records."""
    return float(losses.psnr(image.detach().clamp(0, 1), view.image))
