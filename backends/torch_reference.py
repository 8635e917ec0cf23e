"""The reference renderer: the 3DGS rasterizer of docs/rendering.md in plain PyTorch, differentiated by
autograd. Readable rather than fast; any device, float32 or float64. The contract suite's oracle.
"""

from __future__ import annotations

import attrs
import torch

from mmcsplat.backends.torch_projection import Projection, project
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.render_contract import (
    ALPHA_MAX,
    ALPHA_MIN,
    DEPTH_EPS,
    TILE_SIZE,
    TRANSMITTANCE_MIN,
    Gaussians,
    RenderCameras,
    RenderOutput,
    validate_render_inputs,
)

#: The Gaussian parameters, in the order of :class:`Gaussians`' fields.
FIELDS = tuple(field.name for field in attrs.fields(Gaussians))


def composite(
    pixels: torch.Tensor, means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor, values: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Blend K depth-sorted Gaussians front to back into P pixels ("Compositing" in docs/rendering.md).

    pixels [P, 2] (x, y) sample points; means2d [K, 2], conics [K, 3], opacities [K], values [K, D] (the
    channels to blend, e.g. colour, features and depth). Returns (Σ αᵢ Tᵢ valuesᵢ [P, D], final
    transmittance T [P]).
    """
    d = pixels[:, None, :] - means2d[None, :, :]  # [P, K, 2]
    dx, dy = d[..., 0], d[..., 1]
    a, b, c = conics.unbind(-1)
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    alpha = torch.clamp(opacities * torch.exp(power), max=ALPHA_MAX)
    alpha = torch.where((power <= 0) & (alpha >= ALPHA_MIN), alpha, torch.zeros_like(alpha))
    # Stop before the Gaussian that would bring T below 1e-4: with skipped Gaussians at α = 0, the running
    # product after each Gaussian is its T', and T' only decreases, so the kept ones are a prefix.
    keep = torch.cumprod(1 - alpha, dim=1).detach() >= TRANSMITTANCE_MIN
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    transmittance = torch.cumprod(1 - alpha, dim=1)  # T after each Gaussian; 1 − α ≥ 0.01, never 0
    before = torch.cat([torch.ones_like(transmittance[:, :1]), transmittance[:, :-1]], dim=1)
    return (alpha * before) @ values, transmittance[:, -1]


def tile_pixels(tx: int, ty: int, width: int, height: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """[P, 2] (x, y) pixel centres of tile (tx, ty), row-major, clipped to the image (OpenCV centres:
    pixel (u, v) is sampled at (u, v))."""
    us = torch.arange(tx * TILE_SIZE, min((tx + 1) * TILE_SIZE, width), dtype=dtype, device=device)
    vs = torch.arange(ty * TILE_SIZE, min((ty + 1) * TILE_SIZE, height), dtype=dtype, device=device)
    v, u = torch.meshgrid(vs, us, indexing="ij")
    return torch.stack([u.reshape(-1), v.reshape(-1)], dim=-1)


def rasterize_camera(proj: Projection, camera: int, values: torch.Tensor, width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite one camera tile by tile: (Σ αᵢ Tᵢ valuesᵢ [H·W, D], final T [H·W]) in row-major pixel
    order. ``values`` [N, D] are the channels to blend."""
    dtype, device = values.dtype, values.device
    # Front to back: z ascending, ties by Gaussian index (a stable sort keeps index order).
    order = torch.sort(proj.depths[camera], stable=True).indices
    x0, x1, y0, y1 = proj.tiles[camera][order].unbind(-1)
    pixel_index = torch.arange(height * width, device=device).reshape(height, width)
    sums, transmittances, indices = [], [], []
    for ty in range(-(-height // TILE_SIZE)):
        rows = (y0 <= ty) & (ty < y1)
        for tx in range(-(-width // TILE_SIZE)):
            ids = order[rows & (x0 <= tx) & (tx < x1)]
            if ids.numel() == 0:
                continue
            pixels = tile_pixels(tx, ty, width, height, dtype, device)
            summed, transmittance = composite(
                pixels, proj.means2d[camera, ids], proj.conics[camera, ids], proj.opacities[ids], values[ids]
            )
            sums.append(summed)
            transmittances.append(transmittance)
            indices.append(pixel_index[ty * TILE_SIZE : (ty + 1) * TILE_SIZE, tx * TILE_SIZE : (tx + 1) * TILE_SIZE].reshape(-1))
    summed = values.new_zeros((height * width, values.shape[1]))
    transmittance = values.new_ones(height * width)
    if indices:
        index = torch.cat(indices)
        summed = summed.index_put((index,), torch.cat(sums))
        transmittance = transmittance.index_put((index,), torch.cat(transmittances))
    return summed, transmittance


def rasterize(gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> RenderOutput:
    """Render C cameras with the reference rasterizer; outputs have the dtype and device of ``means``.

    Differentiable by autograd with respect to every Gaussian parameter and ``RenderOutput.means2d`` (a
    zero [C, N, 2] leaf, requiring grad when any parameter does).
    """
    validate_render_inputs(gaussians, cameras, background)
    params = [getattr(gaussians, field) for field in FIELDS]
    needs_grad = torch.is_grad_enabled() and any(p.requires_grad for p in params)
    means2d = gaussians.means.new_zeros((cameras.count, gaussians.count, 2)).requires_grad_(needs_grad)
    return rasterize_with_offset(gaussians, cameras, means2d, background)


def rasterize_with_offset(
    gaussians: Gaussians, cameras: RenderCameras, means2d: torch.Tensor, background: torch.Tensor | None = None
) -> RenderOutput:
    """:func:`rasterize` with the caller's [C, N, 2] 2D-mean offset (zero for the contract's outputs;
    any value for checking gradients); inputs are assumed validated."""
    dtype, device = gaussians.means.dtype, gaussians.means.device
    gaussians = Gaussians(*(getattr(gaussians, field).to(dtype) for field in FIELDS))
    proj = project(gaussians, cameras, means2d)
    num_cameras, height, width = cameras.count, int(cameras.height), int(cameras.width)
    num_features = gaussians.features.shape[1]
    if background is None:
        background = gaussians.means.new_zeros(3)
    background = background.to(device=device, dtype=dtype).expand(num_cameras, 3)
    rgb, features, depth, alpha = [], [], [], []
    for camera in range(num_cameras):
        values = torch.cat([gaussians.colors, gaussians.features, proj.depths[camera, :, None]], dim=1)
        summed, transmittance = rasterize_camera(proj, camera, values, width, height)
        summed = summed.reshape(height, width, -1)
        transmittance = transmittance.reshape(height, width)
        opacity = 1 - transmittance
        rgb.append(summed[..., :3] + transmittance[..., None] * background[camera])
        features.append(summed[..., 3 : 3 + num_features])
        depth.append(summed[..., -1] / torch.clamp_min(opacity, DEPTH_EPS))
        alpha.append(opacity)
    return RenderOutput(
        rgb=torch.stack(rgb), features=torch.stack(features), depth=torch.stack(depth), alpha=torch.stack(alpha),
        radii=proj.radii, means2d=means2d,
    )


class TorchReferenceRenderer(Renderer):
    """The ``torch-reference`` backend: :func:`rasterize` behind the :class:`Renderer` interface."""

    def render(self, gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> RenderOutput:
        """Render every camera; see :func:`rasterize`."""
        return rasterize(gaussians, cameras, background)
