"""Coarse to fine: a frame's first training steps on its views at a reduced resolution.

A limb that moved more than its own width since the last frame no longer overlaps where the prediction put
it, and the image loss at full resolution gives it no gradient. Averaged over ``factor`` × ``factor``
pixel blocks, images and masks are smoother and every Gaussian's footprint, measured in pixels, is
``factor`` times smaller relative to the motion, so a fit there still pulls the limb towards its image; the
last steps refine at full size.
"""

from __future__ import annotations

from collections.abc import Sequence

import attrs
import torch

from mmcsplat.plugin_api.interfaces import TrainingView
from mmcsplat.plugin_api.render_contract import RenderCameras
from mmcsplat.scene.camera import Camera, resize_matrix

from .supersampling import block_mean


def coarse_camera(camera: Camera, factor: int) -> Camera:
    """``camera`` imaging each ``factor`` × ``factor`` block of its pixels (from the top left; a remainder
    of rows or columns is left out) as one pixel."""
    return attrs.evolve(camera, K=resize_matrix(1 / factor, 1 / factor) @ camera.K, width=camera.width // factor,
                        height=camera.height // factor)


def area_downsample(image: torch.Tensor, factor: int) -> torch.Tensor:
    """[H, W, ...] → [H // f, W // f, ...] float: each ``factor`` × ``factor`` block's mean, a remainder of
    rows or columns cropped (as :func:`coarse_camera` does)."""
    height, width = image.shape[0] // factor * factor, image.shape[1] // factor * factor
    return block_mean(image[None, :height, :width].float(), factor)[0]


def coarse_view(view: TrainingView, factor: int) -> TrainingView:
    """``view`` at 1 / ``factor`` of its resolution: image, segmentation target and an image backdrop
    area-averaged, the mask where at least half of a block is the subject's."""
    mask = None if view.mask is None else area_downsample(view.mask[..., None], factor)[..., 0] >= 0.5
    seg = None if view.seg_target is None else area_downsample(view.seg_target, factor)
    backdrop = view.backdrop if view.backdrop.dim() == 1 else area_downsample(view.backdrop, factor)
    return TrainingView(coarse_camera(view.camera, factor), view.index, area_downsample(view.image, factor), mask, seg, backdrop)


class CoarseToFine:
    """The views and render cameras of a frame's steps: for the first ``coarse_steps`` steps each view at
    1 / ``factor`` resolution, then at full size. ``views`` are the frame's views; ``cameras[i]`` renders
    training camera ``i``."""

    def __init__(self, views: Sequence[TrainingView], cameras: Sequence[RenderCameras], factor: int, coarse_steps: int) -> None:
        self.views = list(views)
        self.cameras = cameras
        self.factor = factor
        self.coarse_steps = coarse_steps
        self._coarse: dict[int, tuple[TrainingView, RenderCameras]] = {}

    def at(self, step: int, position: int) -> tuple[TrainingView, RenderCameras]:
        """The view ``views[position]`` and its render cameras for training step ``step``."""
        view = self.views[position]
        if step >= self.coarse_steps or self.factor == 1:
            return view, self.cameras[view.index]
        if position not in self._coarse:
            coarse = coarse_view(view, self.factor)
            self._coarse[position] = (coarse, RenderCameras.from_cameras([coarse.camera], self.cameras[view.index].K.dtype))
        return self._coarse[position]
