"""The cheap part of the render contract, checked on every call of a renderer plugin.

The contract suite (mmcsplat.testing.renderer_contract) tests a renderer thoroughly, but only when its
author runs it. At run time a renderer that returns the wrong shapes or non-finite images from finite
inputs would otherwise surface as a broadcasting error deep in a loss, or as a fit that "completes" on
NaN; here it is an error naming the renderer and what it returned. Shapes and a finiteness test of the
image cost microseconds beside a render.
"""

from __future__ import annotations

import torch

from mmcsplat.plugin_api.errors import PluginError
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras, RenderOutput, all_finite
from mmcsplat.training.plugin_hooks import plugin_hook


class RendererContractError(PluginError):
    """A renderer plugin returned something the render contract does not allow."""


class CheckedRenderer(Renderer):
    """``renderer`` (registered as ``name``) with its outputs checked; the outputs pass through unchanged."""

    def __init__(self, renderer: Renderer, name: str) -> None:
        self.renderer = renderer
        self.name = name

    def render(self, gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> RenderOutput:
        """The wrapped renderer's output, after the checks."""
        with plugin_hook("renderer", self.name, "render"):
            output = self.renderer.render(gaussians, cameras, background)
        if not isinstance(output, RenderOutput):
            raise RendererContractError(f"renderer {self.name!r} returned {type(output).__name__}, not a RenderOutput")
        c, h, w, n = cameras.count, int(cameras.height), int(cameras.width), gaussians.count
        expected = {"rgb": (c, h, w, 3), "features": (c, h, w, gaussians.features.shape[1]), "depth": (c, h, w), "alpha": (c, h, w),
                    "radii": (c, n), "means2d": (c, n, 2)}
        for field, shape in expected.items():
            actual = tuple(getattr(output, field).shape)
            if actual != shape:
                raise RendererContractError(f"renderer {self.name!r} returned {field} of shape {list(actual)} for {c} camera(s) of "
                                            f"{w}×{h} and {n} Gaussians; the contract is {list(shape)}")
        for field in ("rgb", "alpha"):
            if not all_finite(getattr(output, field)):  # inputs were finite (validate_render_inputs)
                raise RendererContractError(f"renderer {self.name!r} returned a non-finite {field} from finite Gaussians and cameras")
        return output
