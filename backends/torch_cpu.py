"""The ``torch-cpu`` renderer: the fast CPU path, for users without a GPU.

Projection (:mod:`mmcsplat.backends.cpu_projection`), binning and compositing
(:mod:`mmcsplat.backends.cpu_raster`) are numba kernels threaded over Gaussians and tiles, each behind a
torch.autograd.Function with a hand-written backward. The compositing kernel also assembles the outputs
(background, depth normalisation, output dtype), so that only [N]- and [C, N]-sized glue is torch
autograd. Everything is computed in float64 and returned in the input's dtype: on this path float64 costs
next to nothing (the kernels are latency-bound scalar code) and keeps the backward's transmittance
recovery and the float32 outputs within rounding of the reference.
Camera poses and intrinsics are not differentiated. Conventions: docs/rendering.md.
"""

from __future__ import annotations

import threading

import attrs
import numpy as np
import torch
from torch.autograd.function import once_differentiable

from mmcsplat.backends import cpu_projection, cpu_raster
from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras, RenderOutput, validate_render_inputs

_DTYPE = torch.float64
#: numba's workqueue threading layer aborts on concurrent launches; renders already use every core, so
#: concurrent calls from several Python threads simply take turns.
_KERNEL_LOCK = threading.Lock()


def _numpy(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().contiguous().numpy()


@attrs.frozen(eq=False)
class Binning:
    """Depth-sorted per-tile Gaussian lists of one render (see :func:`cpu_raster.bin_gaussians`)."""

    extent: np.ndarray
    offsets: np.ndarray
    ids: np.ndarray
    width: int
    height: int


class _Project(torch.autograd.Function):
    """(means2d [C, N, 2], conics [C, N, 3], depths [C, N], radii [C, N], tiles [C, N, 4]) of the Gaussians
    in the cameras; differentiable in means, quats and log-scales (all float64)."""

    @staticmethod
    def forward(ctx, means, quats, log_scales, cameras: RenderCameras):  # noqa: D102 (torch API)
        arrays = [_numpy(t) for t in (means, quats, log_scales, cameras.viewmats.to(_DTYPE), cameras.K.to(_DTYPE))]
        size = (int(cameras.width), int(cameras.height))
        with _KERNEL_LOCK:
            means2d, conics, depths, radii, tiles = cpu_projection.project_forward(*arrays, *size)
        ctx.arrays, ctx.size = arrays, size
        ctx.radii = radii
        radii, tiles = torch.from_numpy(radii), torch.from_numpy(tiles)
        ctx.mark_non_differentiable(radii, tiles)
        return torch.from_numpy(means2d), torch.from_numpy(conics), torch.from_numpy(depths), radii, tiles

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_means2d, grad_conics, grad_depths, _radii, _tiles):  # noqa: D102 (torch API)
        grads = [_numpy(g.to(_DTYPE)) for g in (grad_means2d, grad_conics, grad_depths)]
        with _KERNEL_LOCK:
            g_means, g_quats, g_log_scales = cpu_projection.project_backward(*ctx.arrays, *ctx.size, ctx.radii, *grads)
        return torch.from_numpy(g_means), torch.from_numpy(g_quats), torch.from_numpy(g_log_scales), None


def _bin(means2d, conics, opacities, depths, tiles, width: int, height: int) -> Binning:
    """Depth-sorted per-tile lists of the projected Gaussians."""
    arrays = [_numpy(t) for t in (means2d, conics, opacities, depths, tiles)]
    with _KERNEL_LOCK:
        extent, offsets, ids = cpu_raster.bin_gaussians(*arrays, width, height)
    return Binning(extent, offsets, ids, width, height)


class _Composite(torch.autograd.Function):
    """(rgb, features, depth, alpha) images of the projected Gaussians, in ``dtype``; differentiable in
    means2d, conics, opacities, colors, features, depths (float64) and the background [C, 3]."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, features, depths, background, binning: Binning, dtype):  # noqa: D102
        b = binning
        n_cams, n_feat = depths.shape[0], features.shape[1]
        images = (
            torch.empty((n_cams, b.height, b.width, 3), dtype=dtype),
            torch.empty((n_cams, b.height, b.width, n_feat), dtype=dtype),
            torch.empty((n_cams, b.height, b.width), dtype=dtype),
            torch.empty((n_cams, b.height, b.width), dtype=dtype),
        )
        inputs = [_numpy(t) for t in (means2d, conics, opacities)] + [b.extent]
        inputs += [_numpy(t) for t in (colors, features, depths, background)]
        with _KERNEL_LOCK:
            state = cpu_raster.composite_forward(*inputs, b.offsets, b.ids, b.width, b.height, *(t.numpy() for t in images))
        ctx.inputs, ctx.state, ctx.binning = inputs, state, b
        return images

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_rgb, grad_features, grad_depth, grad_alpha):  # noqa: D102 (torch API)
        b = ctx.binning
        grads = [_numpy(g) for g in (grad_rgb, grad_features, grad_depth, grad_alpha)]
        with _KERNEL_LOCK:
            rows = cpu_raster.composite_backward(*ctx.inputs, b.offsets, b.ids, b.width, b.height, *ctx.state, *grads)
        rows = torch.from_numpy(rows)
        g, n_feat = cpu_raster.GRAD_VALUES, ctx.inputs[5].shape[1]
        grad_background = None
        if ctx.needs_input_grad[6]:  # rgb = colour + T·background
            grad_background = torch.einsum("chwk,chw->ck", grad_rgb.to(_DTYPE), torch.from_numpy(ctx.state[0]))
        return (
            rows[..., 0:2], rows[..., 2:5], rows[..., 5].sum(0), rows[..., g:g + 3].sum(0),
            rows[..., g + 3:g + 3 + n_feat].sum(0), rows[..., -1], grad_background, None, None,
        )


def rasterize(gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> RenderOutput:
    """Render C cameras on the CPU; outputs have the dtype of ``means``.

    Differentiable with respect to every Gaussian parameter, the background and ``RenderOutput.means2d``
    (a zero [C, N, 2] leaf, requiring grad when any parameter does and grad mode is on).
    """
    validate_render_inputs(gaussians, cameras, background)
    dtype = gaussians.means.dtype
    params = [getattr(gaussians, f) for f in ("means", "quats", "log_scales", "opacity_logits", "colors", "features")]
    tensors = [*params, cameras.K, cameras.viewmats] + ([] if background is None else [background])
    if any(t.device.type != "cpu" for t in tensors):
        raise InputError("the torch-cpu renderer needs CPU tensors (Gaussians, cameras and background); "
                         "use torch-cuda or torch-reference on a GPU")
    n_cams, n = cameras.count, gaussians.count
    width, height = int(cameras.width), int(cameras.height)
    needs_grad = torch.is_grad_enabled() and any(p.requires_grad for p in params)
    means2d = torch.zeros((n_cams, n, 2), dtype=dtype, requires_grad=needs_grad)
    g64 = Gaussians(*(p.to(_DTYPE) for p in params))
    xy, conics, depths, radii, tiles = _Project.apply(g64.means, g64.quats, g64.log_scales, cameras)
    xy = xy + means2d.to(_DTYPE)
    opacities = torch.sigmoid(g64.opacity_logits)
    binning = _bin(xy, conics, opacities, depths, tiles, width, height)
    bg = torch.zeros(3, dtype=_DTYPE) if background is None else background.to(_DTYPE)
    kernel_dtype = dtype if dtype in (torch.float32, torch.float64) else torch.float32  # numba has no half types
    images = _Composite.apply(xy, conics, opacities, g64.colors, g64.features, depths, bg.expand(n_cams, 3), binning, kernel_dtype)
    return RenderOutput(*(image.to(dtype) for image in images), radii=radii, means2d=means2d)


class TorchCpuRenderer(Renderer):
    """The ``torch-cpu`` backend: :func:`rasterize` behind the :class:`Renderer` interface."""

    def render(self, gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> RenderOutput:
        """Render every camera; see :func:`rasterize`."""
        return rasterize(gaussians, cameras, background)
