"""SSIM's per-pixel map and its gradient as numba loops, for images on the CPU.

In torch the map is two grouped convolutions (oneDNN) over the five local moments and some twenty
image-sized operations with their autograd: on the Pose2Sim demo's tracking crops (about 265 × 156 × 3)
14 ms of a step's convolutions on one thread, the largest item after the compositor. Here the separable
blur runs along each image row over all of its pixels' channels at once, which vectorises, and the map's
derivative is written out, so that the backward is one more blur, of three maps (five when the target
needs a gradient too). The torch version (:func:`mmcsplat.training.losses.ssim_map_reference`) stays the
oracle the tests hold this to, and the path for other devices.

The window is the study's (Gaussian, 11 taps, σ 1.5, zero padding), and the blur of a zero-padded image by
a symmetric kernel is its own adjoint: the backward blurs the map's partial derivatives by the same loops.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit
from torch.autograd.function import once_differentiable

_KERNEL = {"cache": True, "fastmath": False}


@njit(**_KERNEL)
def blur(maps, taps, step):  # pragma: no cover - numba
    """``maps`` [K, H, L] blurred by ``taps`` along H, and along L between elements ``step`` apart (an
    [H, W, C] image flattened to [H, W·C] has ``step`` C), zero outside: a new array."""
    count, height, length = maps.shape
    reach = len(taps) // 2
    out = np.zeros_like(maps)
    column = np.zeros(length, dtype=maps.dtype)
    row = np.zeros(length + 2 * reach * step, dtype=maps.dtype)
    for k in range(count):
        for i in range(height):
            column[:] = 0
            for t in range(len(taps)):
                source = i + t - reach
                if 0 <= source < height:
                    weight = taps[t]
                    line = maps[k, source]
                    for q in range(length):
                        column[q] += weight * line[q]
            row[reach * step:reach * step + length] = column
            target = out[k, i]
            for t in range(len(taps)):
                weight = taps[t]
                shifted = row[t * step:t * step + length]  # a view: indices numba knows are ≥ 0 vectorise
                for q in range(length):
                    target[q] += weight * shifted[q]
    return out


@njit(**_KERNEL)
def ssim_forward(x, y, taps, step, c1, c2):  # pragma: no cover - numba
    """The SSIM map of ``x`` and ``y`` [H, L] (images flattened as :func:`blur` reads them), and the five
    blurred moments μx, μy, E[x²], E[y²], E[xy] the backward needs."""
    height, length = x.shape
    moments = np.empty((5, height, length), dtype=x.dtype)
    for i in range(height):
        for q in range(length):
            a, b = x[i, q], y[i, q]
            moments[0, i, q] = a
            moments[1, i, q] = b
            moments[2, i, q] = a * a
            moments[3, i, q] = b * b
            moments[4, i, q] = a * b
    blurred = blur(moments, taps, step)
    similarity = np.empty_like(x)
    for i in range(height):
        for q in range(length):
            mx, my = blurred[0, i, q], blurred[1, i, q]
            numerator = (2 * mx * my + c1) * (2 * (blurred[4, i, q] - mx * my) + c2)
            denominator = (mx * mx + my * my + c1) * (blurred[2, i, q] - mx * mx + blurred[3, i, q] - my * my + c2)
            similarity[i, q] = numerator / denominator
    return similarity, blurred


@njit(**_KERNEL)
def ssim_backward(grad_map, x, y, blurred, taps, step, c1, c2, with_target):  # pragma: no cover - numba
    """The gradients in ``x`` and, ``with_target``, in ``y`` (else an empty array) of Σ grad_map · SSIM(x, y)."""
    height, length = x.shape
    # grad_map · ∂S/∂(blurred moment), for μx, E[x²], E[xy], and (with_target) μy, E[y²]: S = similar·covariance / (means·variances)
    partials = np.empty((5 if with_target else 3, height, length), dtype=x.dtype)
    for i in range(height):
        for q in range(length):
            mx, my = blurred[0, i, q], blurred[1, i, q]
            similar = 2 * mx * my + c1
            covariance = 2 * (blurred[4, i, q] - mx * my) + c2
            means = mx * mx + my * my + c1
            variances = blurred[2, i, q] - mx * mx + blurred[3, i, q] - my * my + c2
            ratio = grad_map[i, q] / (means * variances)
            value = similar * covariance * ratio
            shared = 2 * (covariance - similar) * ratio
            spread = 2 * value * (1 / means - 1 / variances)
            partials[0, i, q] = my * shared - mx * spread
            partials[1, i, q] = -value / variances
            partials[2, i, q] = 2 * similar * ratio
            if with_target:
                partials[3, i, q] = mx * shared - my * spread
                partials[4, i, q] = -value / variances
    back = blur(partials, taps, step)
    grad_x = np.empty_like(x)
    grad_y = np.empty_like(y) if with_target else np.empty((0, 0), dtype=y.dtype)
    for i in range(height):
        for q in range(length):
            grad_x[i, q] = back[0, i, q] + 2 * x[i, q] * back[1, i, q] + y[i, q] * back[2, i, q]
            if with_target:
                grad_y[i, q] = back[3, i, q] + 2 * y[i, q] * back[4, i, q] + x[i, q] * back[2, i, q]
    return grad_x, grad_y


class SSIMMap(torch.autograd.Function):
    """Per-pixel SSIM of two [H, W, C] CPU images (:func:`ssim_forward`), differentiable in both."""

    @staticmethod
    def forward(ctx, image, target, taps, c1: float, c2: float):  # noqa: D102 (torch API)
        height, width, channels = image.shape
        dtype = torch.float64 if image.dtype == torch.float64 else torch.float32  # half precision computes in float32
        x, y, weights = (tensor.detach().to(dtype).contiguous().numpy() for tensor in (image, target, taps))
        x, y = x.reshape(height, width * channels), y.reshape(height, width * channels)
        c1, c2 = weights.dtype.type(c1), weights.dtype.type(c2)
        similarity, blurred = ssim_forward(x, y, weights, channels, c1, c2)
        ctx.saved = (x, y, blurred, weights, channels, c1, c2, dtype)
        return torch.from_numpy(similarity.reshape(height, width, channels)).to(image.dtype)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_output):  # noqa: D102 (torch API)
        x, y, blurred, weights, channels, c1, c2, dtype = ctx.saved
        grad = grad_output.to(dtype).contiguous().numpy().reshape(x.shape)
        grad_x, grad_y = ssim_backward(grad, x, y, blurred, weights, channels, c1, c2, bool(ctx.needs_input_grad[1]))
        shape = grad_output.shape
        return (torch.from_numpy(grad_x.reshape(shape)).to(grad_output.dtype) if ctx.needs_input_grad[0] else None,
                torch.from_numpy(grad_y.reshape(shape)).to(grad_output.dtype) if ctx.needs_input_grad[1] else None,
                None, None, None)
