"""The ``jax`` renderer backend: the JAX rasterizer behind the torch :class:`~mmcsplat.plugin_api.interfaces.Renderer`
interface, for the torch trainer.

A ``torch.autograd.Function`` hands the tensors to JAX through DLPack (zero-copy where both sides share
the device), runs the jit-compiled forward under ``jax.vjp`` and, in ``backward``, applies the saved vjp
to the output cotangents. Computation is float32; float64 inputs are computed in float64 only when JAX
runs with x64 enabled (``jax.config.update("jax_enable_x64", True)``), otherwise cast to float32.
Outputs have the computation's dtype; gradients come back in each input's dtype.
"""

from __future__ import annotations

import warnings

import attrs
import jax
import jax.numpy as jnp
import torch
import torch.utils.dlpack

from mmcsplat.backends.jax_buckets import JaxRasterizer, Prepared
from mmcsplat.backends.jax_raster import GAUSSIAN_FIELDS, CameraArrays, GaussianArrays
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.parameters import above, at_least, parameter
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras, RenderOutput, validate_render_inputs

_warned: set[str] = set()


def _warn_once(message: str) -> None:
    """Warn about a fallback once per distinct message, not at every render."""
    if message not in _warned:
        _warned.add(message)
        warnings.warn(message, RuntimeWarning, stacklevel=3)


def to_jax(tensor: torch.Tensor) -> jax.Array:
    """A torch tensor as a JAX array, through DLPack (zero-copy on a shared device). Falls back to a
    host copy through NumPy when DLPack cannot carry it (e.g. a CUDA tensor while JAX runs on the CPU),
    and warns once with the reason."""
    tensor = tensor.detach().contiguous()
    try:
        return jax.dlpack.from_dlpack(tensor)
    except Exception as error:  # noqa: BLE001 - any DLPack failure has the same remedy
        _warn_once(f"DLPack could not pass a {tensor.device} tensor to JAX ({error}); copying through host memory")
        return jnp.asarray(tensor.cpu().numpy())


def to_torch(array: jax.Array, device: torch.device) -> torch.Tensor:
    """A JAX array as a torch tensor on ``device``, through DLPack; a NumPy copy if that fails."""
    try:
        tensor = torch.utils.dlpack.from_dlpack(array)
    except Exception as error:  # noqa: BLE001
        _warn_once(f"DLPack could not pass a JAX array to torch ({error}); copying through host memory")
        tensor = torch.from_numpy(jax.device_get(array).copy())
    return tensor.to(device)


def _pad_rows(tensor: torch.Tensor, rows: int, fill: tuple[float, ...] | None = None) -> torch.Tensor:
    """``tensor`` padded along its first axis to ``rows`` with zeros (or rows equal to ``fill``); padding
    in torch spares JAX a padding program for every new Gaussian count."""
    extra = rows - tensor.shape[0]
    if extra == 0:
        return tensor
    pad = tensor.new_zeros((extra, *tensor.shape[1:])) if fill is None else tensor.new_tensor(fill).expand(extra, -1)
    return torch.cat([tensor, pad])


def _jax_inputs(
    rasterizer: JaxRasterizer, cameras: RenderCameras, dtype: torch.dtype, background: torch.Tensor,
    means2d: torch.Tensor, params: list[torch.Tensor],
) -> tuple[Prepared, CameraArrays]:
    """The rasterizer's inputs: Gaussians and means2d padded (in torch) to their bucket, in ``dtype``."""
    count = params[0].shape[0]
    rows = rasterizer.padded_size(count)
    fills = {"quats": (1.0, 0.0, 0.0, 0.0)}  # an identity rotation keeps the padding's projection finite
    gaussians = GaussianArrays(*(to_jax(_pad_rows(p.to(dtype), rows, fills.get(f))) for f, p in zip(GAUSSIAN_FIELDS, params)))
    offsets = to_jax(_pad_rows(means2d.to(dtype).transpose(0, 1), rows).transpose(0, 1))
    jax_cameras = CameraArrays(to_jax(cameras.K.to(dtype)), to_jax(cameras.viewmats.to(dtype)))
    return rasterizer.prepare(gaussians, jax_cameras, to_jax(background.to(dtype)), offsets, count=count), jax_cameras


class _JaxRender(torch.autograd.Function):
    """(Gaussian parameters, background, means2d) → (rgb, features, depth, alpha, radii) through JAX."""

    @staticmethod
    def forward(ctx, rasterizer: JaxRasterizer, cameras: RenderCameras, dtype: torch.dtype, background, means2d, *params):
        device = params[0].device
        ctx.dtypes = (background.dtype, means2d.dtype, *(p.dtype for p in params))
        # JAX may read the inputs' memory until backward (DLPack shares it): saving them lets torch's version
        # counters reject an in-place change in between, as for any autograd input.
        ctx.save_for_backward(background, means2d, *params)
        prepared, jax_cameras = _jax_inputs(rasterizer, cameras, dtype, background, means2d, list(params))
        images, vjp, radii = rasterizer.forward_with_vjp(prepared, jax_cameras, int(cameras.width), int(cameras.height))
        ctx.rasterizer, ctx.vjp, ctx.count = rasterizer, vjp, prepared.count
        radii = to_torch(radii, device)[:, : prepared.count]  # sliced in torch: no JAX program per N
        ctx.mark_non_differentiable(radii)
        # Copies, because the vjp may hold the same buffers (alpha, for the depth's gradient) and an in-place
        # edit of an output must not change the gradient.
        return (*(to_torch(image, device).clone() for image in images), radii)

    @staticmethod
    def backward(ctx, grad_rgb, grad_features, grad_depth, grad_alpha, _grad_radii):
        _ = ctx.saved_tensors  # raises if an input was modified in place since forward
        cotangents = tuple(to_jax(g) for g in (grad_rgb, grad_features, grad_depth, grad_alpha))
        gaussians, background, means2d = ctx.rasterizer.backward(ctx.vjp, cotangents)
        device, n = grad_rgb.device, ctx.count
        grads = [to_torch(background, device), to_torch(means2d, device)[:, :n]]
        grads += [to_torch(getattr(gaussians, field), device)[:n] for field in GAUSSIAN_FIELDS]
        return None, None, None, *(g.to(dtype) for g, dtype in zip(grads, ctx.dtypes, strict=True))


def _divides_tile(_instance: object, field: attrs.Attribute, value: int) -> None:
    if 16 % value:
        raise ValueError(f"{field.name} must divide the 16-pixel tile (1, 2, 4, 8 or 16), got {value!r}")


@attrs.define
class JaxRenderer(Renderer):
    """The ``jax`` backend (lists and bucketing: :class:`~mmcsplat.backends.jax_buckets.JaxRasterizer`);
    one instance keeps its compiled programs, so reuse it across a run."""

    block_size: int = parameter(32, doc="Gaussians per list block", validator=at_least(1))
    cell_size: int = parameter(8, doc="pixels per side of a bucketing cell; divides the 16-pixel tile",
                               validator=[at_least(1), _divides_tile])
    ratio: float = parameter(1.25, doc="growth factor between bucket sizes", validator=above(1))
    #: The rasterizer, with its compiled programs and learnt capacities (internal state, not a parameter).
    rasterizer: JaxRasterizer = attrs.field(init=False, repr=False, eq=False)

    def __attrs_post_init__(self) -> None:
        self.rasterizer = JaxRasterizer(block_size=self.block_size, cell_size=self.cell_size, ratio=self.ratio)

    def render(self, gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> RenderOutput:
        """Render every camera; differentiable with respect to every Gaussian parameter, the background
        and ``RenderOutput.means2d``."""
        validate_render_inputs(gaussians, cameras, background)
        params = [getattr(gaussians, field) for field in GAUSSIAN_FIELDS]
        means = gaussians.means
        x64 = means.dtype == torch.float64 and jax.config.jax_enable_x64
        dtype = torch.float64 if x64 else torch.float32
        num_cameras = cameras.count
        needs_grad = torch.is_grad_enabled() and any(p.requires_grad for p in params)
        means2d = torch.zeros((num_cameras, gaussians.count, 2), dtype=means.dtype, device=means.device, requires_grad=needs_grad)
        if background is None:
            background = means.new_zeros(3)
        background = background.to(device=means.device).expand(num_cameras, 3)
        if needs_grad:
            rgb, features, depth, alpha, radii = _JaxRender.apply(self.rasterizer, cameras, dtype, background, means2d, *params)
        else:  # a forward-only program: no residuals kept for a backward that will not come
            prepared, jax_cameras = _jax_inputs(self.rasterizer, cameras, dtype, background, means2d, params)
            result = self.rasterizer.render_prepared(prepared, jax_cameras, int(cameras.width), int(cameras.height))
            rgb, features, depth, alpha, radii = (
                to_torch(x, means.device) for x in (result.rgb, result.features, result.depth, result.alpha, result.radii)
            )
            radii = radii[:, : gaussians.count]
        return RenderOutput(rgb=rgb, features=features, depth=depth, alpha=alpha, radii=radii, means2d=means2d)
