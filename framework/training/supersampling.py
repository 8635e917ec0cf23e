"""Pixels that integrate over their area: render at N× and average each N × N block.

A renderer samples each Gaussian at the pixel centre; a camera's pixel integrates the light over its
area, and so does the synthetic capture (2 × 2 rays per pixel, ``mmcsplat synth``). At 256 × 192 the
infant is some 40 pixels across and its textures change within a pixel, so point samples and area
averages differ; a fit that renders like the camera learns texture below the pixel that other views
agree on. :class:`SupersampledRenderer` wraps any backend; a run fitted with ``fit.supersample = N``
is evaluated, tracked and rendered with it too (:func:`run_renderer`).
"""

from __future__ import annotations

import attrs
import torch

from mmcsplat.configuration.registry import Registry
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras, RenderOutput
from mmcsplat.scene.camera import resize_matrix
from mmcsplat.storage.run_info import RunInfo
from mmcsplat.training.checked_renderer import CheckedRenderer


def subpixel_cameras(cameras: RenderCameras, factor: int) -> RenderCameras:
    """``cameras`` with every pixel split into ``factor`` × ``factor`` sub-pixels: the image resized by
    ``factor`` (:func:`~mmcsplat.scene.camera.resize_matrix`), so pixel u's sub-pixels are centred at
    u + (2i + 1 − f) / 2f, i = 0 … f − 1."""
    resize = torch.as_tensor(resize_matrix(factor, factor), dtype=cameras.K.dtype, device=cameras.K.device)
    return RenderCameras(resize @ cameras.K, cameras.viewmats, cameras.width * factor, cameras.height * factor)


def block_mean(images: torch.Tensor, factor: int) -> torch.Tensor:
    """[C, fH, fW, ...] → [C, H, W, ...]: the mean of each ``factor`` × ``factor`` block."""
    count, height, width = images.shape[:3]
    blocks = images.reshape(count, height // factor, factor, width // factor, factor, *images.shape[3:])
    return blocks.mean(dim=(2, 4))


class SupersampledRenderer(Renderer):
    """``renderer`` at ``factor`` × the cameras' resolution, each block of sub-pixels averaged into its
    pixel: images, features, alpha and depth (the alpha-weighted mean of the sub-pixels' depths, so
    ``depth`` stays the expected depth of what the pixel shows). ``radii`` and the screen-space gradient
    of ``means2d`` are the sub-pixel render's: a densifier threshold on that gradient (per sub-pixel)
    is reached by 1 / factor of the per-pixel gradient."""

    def __init__(self, renderer: Renderer, factor: int) -> None:
        if factor < 2:
            raise InputError(f"supersampling factor must be at least 2, got {factor}")
        self.renderer = renderer
        self.factor = factor

    def render(self, gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> RenderOutput:
        fine = self.renderer.render(gaussians, subpixel_cameras(cameras, self.factor), background)
        alpha = block_mean(fine.alpha, self.factor)
        weighted_depth = block_mean(fine.depth * fine.alpha, self.factor)
        return attrs.evolve(
            fine,
            rgb=block_mean(fine.rgb, self.factor),
            features=block_mean(fine.features, self.factor),
            depth=torch.where(alpha > 0, weighted_depth / alpha.clamp_min(1e-10), torch.zeros_like(alpha)),
            alpha=alpha,
        )


def supersampled(renderer: Renderer, factor: int) -> Renderer:
    """``renderer`` itself at factor 1, else a :class:`SupersampledRenderer` around it."""
    return renderer if factor == 1 else SupersampledRenderer(renderer, factor)


def run_renderer(info: RunInfo, registry: Registry, backend: str | None = None) -> Renderer:
    """The renderer that shows a fitted run as it was fitted: ``backend`` (default: the run's own), at
    the run's ``fit.supersample``."""
    name = backend or info.renderer
    return supersampled(CheckedRenderer(registry.create("renderer", name), name), info.supersample)
