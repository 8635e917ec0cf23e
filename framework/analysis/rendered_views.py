"""What evaluation scores: a camera's view of a run's Gaussians over that camera's backdrop."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from mmcsplat.plugin_api.render_contract import RenderCameras, composite

if TYPE_CHECKING:
    from mmcsplat.plugin_api.interfaces import Renderer
    from mmcsplat.plugin_api.render_contract import Gaussians
    from mmcsplat.scene.camera import Camera


def render_over(renderer: Renderer, gaussians: Gaussians, camera: Camera, backdrop: torch.Tensor) -> torch.Tensor:
    """``camera``'s view of ``gaussians`` over ``backdrop`` ([H, W, 3], no gradients): what evaluation scores."""
    with torch.no_grad():
        return composite(renderer.render(gaussians, RenderCameras.from_cameras([camera])), 0, backdrop)
