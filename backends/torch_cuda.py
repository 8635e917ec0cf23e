"""The ``torch-cuda`` backend: gsplat's CUDA ``rasterization()`` behind the renderer contract.

gsplat (the optional ``cuda`` extra) samples pixel centres at (u + 0.5, v + 0.5), so the principal point
is shifted by half a pixel on the way in (docs/rendering.md, "Pixel centres"). Two constants of its
kernels differ from the page — α is capped at 0.999, and tiles are covered by opacity-aware 3.33σ boxes —
see "Backends wrapping another rasterizer" there. Radii are the page's, from
:mod:`mmcsplat.backends.torch_projection`, so visibility statistics agree across backends.
"""

from __future__ import annotations

import attrs
import torch

from mmcsplat.backends.torch_projection import project
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.parameters import parameter
from mmcsplat.plugin_api.render_contract import (
    LOW_PASS,
    NEAR_PLANE,
    TILE_SIZE,
    Gaussians,
    RenderCameras,
    RenderOutput,
    validate_render_inputs,
)


def _torch_device(_instance: object, field: attrs.Attribute, value: str) -> None:
    try:
        torch.device(value)
    except (RuntimeError, TypeError) as error:
        raise ValueError(f"{field.name} must be a torch device such as 'cuda' or 'cuda:1', got {value!r}") from error


@attrs.frozen
class GsplatRenderer(Renderer):
    """Renders on ``device`` (a CUDA device) in float32; inputs elsewhere are moved there and the images
    moved back, in the input's dtype. ``RenderOutput.means2d`` is gsplat's projected-means tensor (on
    ``device``): its values are the 2D means, its ``.grad`` after backward the contract's screen-space
    gradient."""

    device: str = parameter("cuda", doc="the CUDA device to render on (a torch device string, e.g. cuda:1)", validator=_torch_device)

    def render(self, gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> RenderOutput:
        """Render every camera with ``gsplat.rasterization`` (RGB + expected depth, features as extra channels)."""
        validate_render_inputs(gaussians, cameras, background)
        home, dtype = gaussians.means.device, gaussians.means.dtype
        c, n, f = cameras.count, gaussians.count, gaussians.features.shape[1]
        height, width = int(cameras.height), int(cameras.width)

        def put(tensor: torch.Tensor) -> torch.Tensor:
            return tensor.to(device=self.device, dtype=torch.float32)

        bg = put(background if background is not None else torch.zeros(3)).expand(c, 3)
        if n == 0:  # nothing to rasterize: the background alone
            zeros = torch.zeros((c, height, width), dtype=dtype, device=home)
            return RenderOutput(
                rgb=bg.to(home, dtype)[:, None, None, :].expand(c, height, width, 3).clone(),
                features=zeros.new_zeros((c, height, width, f)), depth=zeros, alpha=zeros.clone(),
                radii=torch.zeros((c, 0), dtype=torch.int32, device=home), means2d=zeros.new_zeros((c, 0, 2)),
            )

        from gsplat import rasterization

        Ks = put(cameras.K).clone()
        Ks[:, 0, 2] += 0.5  # gsplat's pixel (u, v) is sampled at (u + 0.5, v + 0.5); ours at (u, v)
        Ks[:, 1, 2] += 0.5
        images, alphas, meta = rasterization(
            means=put(gaussians.means),
            quats=put(gaussians.quats),
            scales=torch.exp(put(gaussians.log_scales)),
            opacities=torch.sigmoid(put(gaussians.opacity_logits)),
            colors=torch.cat([put(gaussians.colors), put(gaussians.features)], dim=1),
            viewmats=put(cameras.viewmats),
            Ks=Ks,
            width=width,
            height=height,
            near_plane=NEAR_PLANE,
            eps2d=LOW_PASS,
            packed=False,
            tile_size=TILE_SIZE,
            backgrounds=torch.cat([bg, bg.new_zeros((c, f))], dim=1),  # features get no background
            render_mode="RGB+ED",
            absgrad=False,
            rasterize_mode="classic",
        )
        means2d = meta["means2d"]
        if means2d.requires_grad:
            means2d.retain_grad()
        with torch.no_grad():
            plain = Gaussians(*(put(value) for value in attrs.astuple(gaussians, recurse=False)))
            radii = project(plain, cameras, torch.zeros((c, n, 2), device=self.device)).radii
        images = images.to(device=home, dtype=dtype)
        return RenderOutput(
            rgb=images[..., :3],
            features=images[..., 3 : 3 + f],
            depth=images[..., -1],  # gsplat's "ED": Σ wᵢ zᵢ / max(alpha, 1e-10)
            alpha=alphas[..., 0].to(device=home, dtype=dtype),
            radii=radii.to(home),
            means2d=means2d,
        )
