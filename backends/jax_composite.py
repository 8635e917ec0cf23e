"""Front-to-back alpha compositing of depth-sorted Gaussians in fixed-size blocks, in JAX, with a
hand-written backward (a ``jax.custom_vjp``).

The binning step (:mod:`mmcsplat.backends.jax_raster`) lays the depth-sorted Gaussian list of every pixel
cell (a tile or a part of one) out as consecutive *blocks* of ``L`` slots (the last block of a cell padded
with a dummy Gaussian of zero opacity), so the work is proportional to the number of (cell, Gaussian) pairs
however unevenly the cells are loaded. Per pixel, the running transmittance is a prefix sum of
log(1 − α): inside a block a small matrix product over ``L`` slots, across the blocks of one cell a
segmented scan over block totals. Everything is
vectorised; there is no early termination, but the "stop below 1e-4" rule of docs/rendering.md is honoured
exactly by masking, and the backward pass reproduces autograd of the sequential definition (3DGS: the
gradient of αₖ needs the colour still to come behind it, here a reverse segmented prefix sum).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from mmcsplat.plugin_api.render_contract import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN

#: Splat table columns before the blended channels: mean x, mean y, conic a, b, c, opacity.
SPLAT_HEADER = 6
LOG_T_MIN = math.log(TRANSMITTANCE_MIN)


def _exclusive_segment_scan(values: jax.Array, first: jax.Array, reverse: bool) -> jax.Array:
    """Per segment of consecutive blocks, the sum of ``values`` [B, P] over the blocks before (or, with
    ``reverse``, after) each block. ``first`` [B] marks each segment's first block in scan order.

    A sequential scan: blocks are few (≈ pairs / L) and it compiles in a fraction of the time of
    ``lax.associative_scan``; within a segment it adds in order, so small sums stay exact."""

    def step(carry: jax.Array, item: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        starts, value = item
        carry = jnp.where(starts, 0.0, carry)
        return carry + value, carry

    return jax.lax.scan(step, jnp.zeros_like(values[0]), (first, values), reverse=reverse)[1]


def _prefix_matrix(size: int, dtype: jnp.dtype, strict: bool, upper: bool) -> jax.Array:
    """x @ M is the (inclusive or strict) prefix sum (``upper``) or suffix sum along the last axis: a
    small GEMM, several times faster than ``cumsum`` on XLA:CPU."""
    i = jnp.arange(size)
    before = i[:, None] < i[None, :] if upper else i[:, None] > i[None, :]
    return (before | (~strict & (i[:, None] == i[None, :]))).astype(dtype)


def _alphas(splats: jax.Array, pixels: jax.Array) -> tuple[jax.Array, ...]:
    """Per block, pixel and slot: offsets (dx, dy), the Gaussian falloff exp(power), the unclamped
    α̂ = o·exp(power) and the α used (0 where skipped: power > 0 or α < 1/255). Shapes [B, P, L]."""
    mx, my, a, b, c, o = (splats[:, None, :, i] for i in range(SPLAT_HEADER))  # [B, 1, L]
    dx = pixels[..., 0, None] - mx
    dy = pixels[..., 1, None] - my
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    # power > 0 is skipped anyway; capping it keeps exp finite, so masked gradients stay 0, not NaN.
    falloff = jnp.exp(jnp.minimum(power, 0.0))
    raw = o * falloff
    alpha = jnp.minimum(raw, ALPHA_MAX)
    alpha = jnp.where((power <= 0) & (alpha >= ALPHA_MIN), alpha, 0.0)
    return dx, dy, falloff, raw, alpha


def _transmittance(alpha: jax.Array, first: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """log(1 − α), log T before each slot and whether the slot is before the stop (all [B, P, L])."""
    log_keep = jnp.log1p(-alpha)
    inclusive = log_keep @ _prefix_matrix(alpha.shape[-1], alpha.dtype, strict=False, upper=True)
    inclusive = inclusive + _exclusive_segment_scan(inclusive[..., -1], first, reverse=False)[..., None]
    # T' ≥ 1e-4 after the slot ⇔ the slot is composited; T' only decreases, so the kept slots are a prefix.
    alive = inclusive >= LOG_T_MIN
    return log_keep, inclusive - log_keep, alive


def _composite_forward(splats: jax.Array, pixels: jax.Array, first: jax.Array) -> tuple[tuple[jax.Array, jax.Array], tuple[jax.Array, ...]]:
    """Outputs, and what the backward pass reuses: falloff, α of the composited slots (0 elsewhere) and T
    before each slot ([B, P, L] each)."""
    _, _, falloff, _, alpha = _alphas(splats, pixels)
    log_keep, log_before, alive = _transmittance(alpha, first)
    alpha = jnp.where(alive, alpha, 0.0)
    before = jnp.exp(log_before)
    sums = jnp.einsum("bpl,blc->bpc", alpha * before, splats[..., SPLAT_HEADER:])
    log_t = jnp.sum(jnp.where(alive, log_keep, 0.0), axis=-1)
    return (sums, log_t), (falloff, alpha, before)


@jax.custom_vjp
def composite_blocks(splats: jax.Array, pixels: jax.Array, first: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Composite blocks of depth-sorted splats over the pixels of their cell.

    splats [B, L, 6 + D]: per slot (mean x, mean y, conic a, b, c, opacity, D channels to blend), in
    front-to-back order across the consecutive blocks of one cell; pixels [B, P, 2] the (x, y) sample
    points of each block's cell; first [B] bool marks the first block of each cell. Returns each block's
    share of the cell's sums Σ αᵢTᵢ·valuesᵢ [B, P, D] and of its final log-transmittance [B, P]; summing
    the blocks of a cell gives the cell's. Differentiable with respect to ``splats``.
    """
    return _composite_forward(splats, pixels, first)[0]


def _composite_fwd(splats, pixels, first):
    outputs, saved = _composite_forward(splats, pixels, first)
    return outputs, (splats, pixels, first, *saved)


def _composite_bwd(residuals, cotangents):
    splats, pixels, first, falloff, alpha, before = residuals  # α: 0 where skipped or after the stop
    grad_sums, grad_log_t = cotangents  # [B, P, D], [B, P]: a cell's cotangent, repeated for its blocks
    values = splats[..., SPLAT_HEADER:]
    mx, my, a, b, c, o = (splats[:, None, :, i] for i in range(SPLAT_HEADER))  # [B, 1, L]
    dx = pixels[..., 0, None] - mx
    dy = pixels[..., 1, None] - my
    raw = o * falloff
    weight = alpha * before

    grad_values = jnp.einsum("bpl,bpc->blc", weight, grad_sums)
    # dL/dαₖ = Tₖ gₖ − (Σ_{j>k} wⱼ gⱼ + dL/dlog T) / (1 − αₖ), gₖ = values·dL/dsums; the suffix sum spans
    # the later slots of this block and the later blocks of the cell.
    g = jnp.einsum("blc,bpc->bpl", values, grad_sums)
    contribution = weight * g
    suffix = contribution @ _prefix_matrix(alpha.shape[-1], alpha.dtype, strict=True, upper=False)
    last = jnp.concatenate([first[1:], jnp.ones_like(first[:1])])
    suffix = suffix + _exclusive_segment_scan(jnp.sum(contribution, axis=-1), last, reverse=True)[..., None]
    grad_alpha = before * g - (suffix + grad_log_t[..., None]) / (1.0 - alpha)
    # Skipped, clamped (α̂ > 0.99) and stopped slots pass no gradient, as autograd of the forward gives.
    grad_raw = jnp.where((alpha > 0) & (raw < ALPHA_MAX), grad_alpha, 0.0)
    grad_power = grad_raw * raw
    grad_header = jnp.stack(
        [
            jnp.sum(grad_power * (a * dx + b * dy), axis=1),
            jnp.sum(grad_power * (c * dy + b * dx), axis=1),
            jnp.sum(grad_power * (-0.5 * dx * dx), axis=1),
            jnp.sum(grad_power * (-dx * dy), axis=1),
            jnp.sum(grad_power * (-0.5 * dy * dy), axis=1),
            jnp.sum(grad_raw * falloff, axis=1),
        ],
        axis=-1,
    )
    return jnp.concatenate([grad_header, grad_values], axis=-1), None, None


composite_blocks.defvjp(_composite_fwd, _composite_bwd)
