"""Numba kernels of the ``torch-cpu`` renderer: tile binning, front-to-back compositing and its backward.

Pure numpy in and out; :mod:`mmcsplat.backends.torch_cpu` wraps them in a torch.autograd.Function.
Conventions are those of docs/rendering.md. Arrays are indexed camera c, Gaussian i; tiles are numbered
row-major within a camera and flattened camera-major (``ct = c * tiles + t``). Arithmetic is float64
whatever the storage type, so the backward recovers transmittance by division without drift.

Exact optimisations over the reference's "every Gaussian of the tile, every pixel of the tile": a pixel
can only receive α ≥ 1/255 inside the ellipse dᵀ·conic·d ≤ 2·ln(255·o), so each Gaussian visits only the
pixels of that ellipse's bounding box, skips exp outside the ellipse, and is binned only into the tiles
of its 3σ tile rectangle (from the projection) that the box touches. The pixels left out would have been
skipped anyway (the bounds carry a relative slack of 1e-6 over rounding), so the image is unchanged.
Arrays are allocated with np.empty and filled inside the parallel loops: in a parallel=True function each
np.zeros is a parallel region of its own, and every region costs a fork-join, which hurts on an
oversubscribed machine.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from mmcsplat.plugin_api.render_contract import ALPHA_MAX, ALPHA_MIN, DEPTH_EPS, TILE_SIZE, TRANSMITTANCE_MIN

_PARALLEL = {"parallel": True, "cache": True, "fastmath": False, "nogil": True}
_INLINE = {"cache": True, "fastmath": False, "inline": "always"}
#: Per-instance gradient columns: d mean2d (x, y), d conic (a, b, c), d opacity, then the channels'.
GRAD_VALUES = 6
#: Relative and absolute slack on the contribution box: covers the rounding of the power's evaluation.
_BOX_SLACK = 1e-6


@njit(**_INLINE)
def _alpha(dx, dy, a, b, c, o, floor):
    """(α, falloff) of a Gaussian at offset (dx, dy); α = 0 where the pixel is skipped. ``floor`` is a
    power below which α < 1/255 for certain (so exp is not evaluated there)."""
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    if power > 0.0 or power < floor:
        return 0.0, 0.0
    falloff = math.exp(power)
    alpha = min(ALPHA_MAX, o * falloff)
    if alpha < ALPHA_MIN:
        return 0.0, 0.0
    return alpha, falloff


@njit(**_INLINE)
def _span(centre, half, lo, hi):
    """Integer pixel range [start, stop) of [centre − half, centre + half] within [lo, hi)."""
    start = centre - half
    stop = centre + half
    first = lo if start <= lo else min(hi, int(math.ceil(start)))
    last = hi if stop >= hi - 1 else max(lo, int(math.floor(stop)) + 1)
    return first, max(first, last)


@njit(**_PARALLEL)
def bin_gaussians(xy, conic, opacity, depth, tiles_rect, width, height):
    """Per-tile lists of Gaussian ids sorted by (depth, index).

    xy [C, N, 2] 2D means, conic [C, N, 3], opacity [N], depth [C, N] camera z, tiles_rect [C, N, 4] the
    half-open 3σ tile range (x0, x1, y0, y1), empty for culled Gaussians. Returns extent [C, N, 3] (half
    width and height of the contribution box in px, and the power below which α < 1/255), offsets
    [C·tiles + 1] int64 and ids [offsets[-1]] int32: tile ct holds ids[offsets[ct]:offsets[ct + 1]].
    """
    n_cams, n = depth.shape
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    tiles = tiles_x * ((height + TILE_SIZE - 1) // TILE_SIZE)
    extent = np.empty((n_cams, n, 3))
    rect = np.empty((n_cams, n, 4), np.int64)  # the part of tiles_rect the contribution box touches
    counts = np.empty(n_cams * tiles + 1, np.int64)
    counts[0] = 0
    for cam in prange(n_cams):
        base = cam * tiles + 1
        counts[base:base + tiles] = 0
        for i in range(n):
            extent[cam, i, 0] = extent[cam, i, 1] = extent[cam, i, 2] = 0.0
            rect[cam, i, 0] = rect[cam, i, 1] = rect[cam, i, 2] = rect[cam, i, 3] = 0
            x0, x1, y0, y1 = tiles_rect[cam, i, 0], tiles_rect[cam, i, 1], tiles_rect[cam, i, 2], tiles_rect[cam, i, 3]
            o = opacity[i]
            if x1 <= x0 or y1 <= y0 or o < ALPHA_MIN:  # culled, or α = min(0.99, o·falloff) < 1/255 everywhere
                continue
            mx, my = xy[cam, i, 0], xy[cam, i, 1]
            a, b, c = conic[cam, i, 0], conic[cam, i, 1], conic[cam, i, 2]
            det = a * c - b * b
            if det > 0.0:
                reach = 2.0 * math.log(o / ALPHA_MIN)
                floor = -0.5 * reach * (1.0 + _BOX_SLACK) - _BOX_SLACK
                hx = math.sqrt(reach * c / det) * (1.0 + _BOX_SLACK) + _BOX_SLACK
                hy = math.sqrt(reach * a / det) * (1.0 + _BOX_SLACK) + _BOX_SLACK
                x0 = max(x0, math.floor((mx - hx) / TILE_SIZE))
                x1 = min(x1, math.floor((mx + hx) / TILE_SIZE) + 1)
                y0 = max(y0, math.floor((my - hy) / TILE_SIZE))
                y1 = min(y1, math.floor((my + hy) / TILE_SIZE) + 1)
            else:  # numerically indefinite conic: no box, visit the whole 3σ rectangle
                hx = hy = np.inf
                floor = -np.inf
            if x1 <= x0 or y1 <= y0:
                continue
            extent[cam, i, 0] = hx
            extent[cam, i, 1] = hy
            extent[cam, i, 2] = floor
            rect[cam, i, 0], rect[cam, i, 1], rect[cam, i, 2], rect[cam, i, 3] = x0, x1, y0, y1
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    counts[base + ty * tiles_x + tx] += 1
    offsets = np.cumsum(counts)
    ids = np.empty(offsets[-1], np.int32)
    for cam in prange(n_cams):
        cursor = offsets[cam * tiles:(cam + 1) * tiles].copy()
        for i in np.argsort(depth[cam], kind="mergesort"):  # stable: equal depths by index
            x0, x1, y0, y1 = rect[cam, i, 0], rect[cam, i, 1], rect[cam, i, 2], rect[cam, i, 3]
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    t = ty * tiles_x + tx
                    ids[cursor[t]] = i
                    cursor[t] += 1
    return extent, offsets, ids


@njit(**_INLINE)
def _tile_bounds(ct, tiles, tiles_x, width, height):
    """(camera, u0, u1, v0, v1) of flattened tile ``ct``."""
    t = ct % tiles
    u0, v0 = (t % tiles_x) * TILE_SIZE, (t // tiles_x) * TILE_SIZE
    return ct // tiles, u0, min(u0 + TILE_SIZE, width), v0, min(v0 + TILE_SIZE, height)


@njit(**_PARALLEL)
def composite_forward(xy, conic, opacity, extent, colors, features, depths, background, offsets, ids, width, height,
                      rgb, feat, depth, alpha):
    """Front-to-back compositing of every tile of every camera, writing the outputs in place.

    colors [N, 3], features [N, F], depths [C, N] are the composited channels, background [C, 3]; rgb
    [C, H, W, 3], feat [C, H, W, F], depth [C, H, W], alpha [C, H, W] receive colour + T·background, the
    feature sums, Σ wᵢzᵢ / max(alpha, DEPTH_EPS) and alpha = Σ wᵢ (wᵢ = αᵢTᵢ). Returns, for the backward,
    float64 [C, H, W] final transmittance, alpha and depth sum, and last [C, H, W] int32: the number of
    list entries up to and including the pixel's last contributor.
    """
    n_cams = depths.shape[0]
    n_feat = features.shape[1]
    dims = 3 + n_feat + 1  # colour, features, depth
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    tiles = tiles_x * ((height + TILE_SIZE - 1) // TILE_SIZE)
    trans = np.empty((n_cams, height, width))
    weight = np.empty((n_cams, height, width))
    depth_sum = np.empty((n_cams, height, width))
    last = np.empty((n_cams, height, width), np.int32)
    for ct in prange(n_cams * tiles):
        cam, u0, u1, v0, v1 = _tile_bounds(ct, tiles, tiles_x, width, height)
        start, end = offsets[ct], offsets[ct + 1]
        tile_t = np.ones((TILE_SIZE, TILE_SIZE))
        tile_acc = np.zeros((TILE_SIZE, TILE_SIZE, dims))
        tile_w = np.zeros((TILE_SIZE, TILE_SIZE))
        tile_last = np.zeros((TILE_SIZE, TILE_SIZE), np.int32)
        done = np.zeros((TILE_SIZE, TILE_SIZE), np.bool_)
        active = (u1 - u0) * (v1 - v0)
        for k in range(start, end):
            i = ids[k]
            mx, my, o = xy[cam, i, 0], xy[cam, i, 1], opacity[i]
            a, b, c = conic[cam, i, 0], conic[cam, i, 1], conic[cam, i, 2]
            ua, ub = _span(mx, extent[cam, i, 0], u0, u1)
            va, vb = _span(my, extent[cam, i, 1], v0, v1)
            floor = extent[cam, i, 2]
            for v in range(va, vb):
                for u in range(ua, ub):
                    if done[v - v0, u - u0]:
                        continue
                    alpha_i, _ = _alpha(u - mx, v - my, a, b, c, o, floor)
                    if alpha_i == 0.0:
                        continue
                    t_now = tile_t[v - v0, u - u0]
                    t_next = t_now * (1.0 - alpha_i)
                    if t_next < TRANSMITTANCE_MIN:
                        done[v - v0, u - u0] = True
                        active -= 1
                        continue
                    w = alpha_i * t_now
                    acc = tile_acc[v - v0, u - u0]
                    for d in range(3):
                        acc[d] += w * colors[i, d]
                    for d in range(n_feat):
                        acc[3 + d] += w * features[i, d]
                    acc[dims - 1] += w * depths[cam, i]
                    tile_w[v - v0, u - u0] += w
                    tile_t[v - v0, u - u0] = t_next
                    tile_last[v - v0, u - u0] = k - start + 1
            if active == 0:
                break
        for v in range(v0, v1):
            for u in range(u0, u1):
                acc = tile_acc[v - v0, u - u0]
                t_final, w_sum = tile_t[v - v0, u - u0], tile_w[v - v0, u - u0]
                for d in range(3):
                    rgb[cam, v, u, d] = acc[d] + t_final * background[cam, d]
                for d in range(n_feat):
                    feat[cam, v, u, d] = acc[3 + d]
                depth[cam, v, u] = acc[dims - 1] / max(w_sum, DEPTH_EPS)
                alpha[cam, v, u] = w_sum
                trans[cam, v, u], weight[cam, v, u], depth_sum[cam, v, u] = t_final, w_sum, acc[dims - 1]
                last[cam, v, u] = tile_last[v - v0, u - u0]
    return trans, weight, depth_sum, last


@njit(**_PARALLEL)
def composite_backward(xy, conic, opacity, extent, colors, features, depths, background, offsets, ids, width, height,
                       trans, weight, depth_sum, last, grad_rgb, grad_feat, grad_depth, grad_alpha):
    """Gradients of :func:`composite_forward` given d loss / d (rgb, feat, depth, alpha).

    Each pixel walks back from its last contributor, recovering Tᵢ = Tᵢ₊₁ / (1 − αᵢ). Every (tile, Gaussian)
    list entry owns a row of gradients, so tiles run in parallel without races; rows are then summed per
    Gaussian in list order, which makes the result independent of the thread count. Returns [C, N, 6 + D]:
    columns d mean2d (x, y), d conic (a, b, c), d opacity, then d colour (3), d features (F), d depth.
    """
    n_cams, n = depths.shape
    n_feat = features.shape[1]
    dims = 3 + n_feat + 1
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    tiles = tiles_x * ((height + TILE_SIZE - 1) // TILE_SIZE)
    rows = np.empty((ids.shape[0], GRAD_VALUES + dims))
    for ct in prange(n_cams * tiles):
        start = offsets[ct]
        if start == offsets[ct + 1]:
            continue
        cam, u0, u1, v0, v1 = _tile_bounds(ct, tiles, tiles_x, width, height)
        tile_t = np.empty((TILE_SIZE, TILE_SIZE))
        tile_g = np.empty((TILE_SIZE, TILE_SIZE, dims))  # d loss / d Σ wᵢ vᵢ per channel
        # per pixel Σ over later contributors j of wⱼ (g·vⱼ), minus d loss / d alpha · T_final, so that
        # d loss / d αᵢ = Tᵢ (g·vᵢ) − q / (1 − αᵢ)  (alpha = 1 − T_final: d alpha / d αᵢ = T_final / (1 − αᵢ))
        tile_q = np.empty((TILE_SIZE, TILE_SIZE))
        reached = 0
        for v in range(v0, v1):
            for u in range(u0, u1):
                g = tile_g[v - v0, u - u0]
                g_alpha = grad_alpha[cam, v, u]
                for d in range(3):
                    g[d] = grad_rgb[cam, v, u, d]
                    g_alpha -= grad_rgb[cam, v, u, d] * background[cam, d]  # rgb = colour + (1 − alpha)·bg
                for d in range(n_feat):
                    g[3 + d] = grad_feat[cam, v, u, d]
                w_sum = weight[cam, v, u]
                if w_sum >= DEPTH_EPS:  # depth = depth_sum / max(alpha, DEPTH_EPS)
                    g[dims - 1] = grad_depth[cam, v, u] / w_sum
                    g_alpha -= grad_depth[cam, v, u] * depth_sum[cam, v, u] / (w_sum * w_sum)
                else:
                    g[dims - 1] = grad_depth[cam, v, u] / DEPTH_EPS
                tile_t[v - v0, u - u0] = trans[cam, v, u]
                tile_q[v - v0, u - u0] = -g_alpha * trans[cam, v, u]
                reached = max(reached, last[cam, v, u])
        rows[start + reached:offsets[ct + 1]] = 0.0  # entries behind every pixel's last contributor
        grad_v = np.empty(dims)
        for k in range(start + reached - 1, start - 1, -1):
            i = ids[k]
            j = k - start
            mx, my, o = xy[cam, i, 0], xy[cam, i, 1], opacity[i]
            a, b, c = conic[cam, i, 0], conic[cam, i, 1], conic[cam, i, 2]
            ua, ub = _span(mx, extent[cam, i, 0], u0, u1)
            va, vb = _span(my, extent[cam, i, 1], v0, v1)
            floor = extent[cam, i, 2]
            g_mx = g_my = g_a = g_b = g_c = g_o = 0.0
            grad_v[:] = 0.0
            for v in range(va, vb):
                for u in range(ua, ub):
                    if j >= last[cam, v, u]:
                        continue
                    dx, dy = u - mx, v - my
                    alpha_i, falloff = _alpha(dx, dy, a, b, c, o, floor)
                    if alpha_i == 0.0:
                        continue
                    keep = 1.0 - alpha_i
                    t_i = tile_t[v - v0, u - u0] / keep
                    w = alpha_i * t_i
                    g = tile_g[v - v0, u - u0]
                    g_dot_v = g[dims - 1] * depths[cam, i]
                    grad_v[dims - 1] += w * g[dims - 1]
                    for d in range(3):
                        grad_v[d] += w * g[d]
                        g_dot_v += g[d] * colors[i, d]
                    for d in range(n_feat):
                        grad_v[3 + d] += w * g[3 + d]
                        g_dot_v += g[3 + d] * features[i, d]
                    g_alpha_i = t_i * g_dot_v - tile_q[v - v0, u - u0] / keep
                    tile_q[v - v0, u - u0] += w * g_dot_v
                    tile_t[v - v0, u - u0] = t_i
                    if o * falloff > ALPHA_MAX:  # the cap passes no gradient
                        continue
                    g_o += g_alpha_i * falloff
                    g_power = g_alpha_i * alpha_i
                    g_a -= 0.5 * dx * dx * g_power
                    g_c -= 0.5 * dy * dy * g_power
                    g_b -= dx * dy * g_power
                    g_mx += g_power * (a * dx + b * dy)
                    g_my += g_power * (c * dy + b * dx)
            row = rows[k]
            row[0], row[1], row[2], row[3], row[4], row[5] = g_mx, g_my, g_a, g_b, g_c, g_o
            row[GRAD_VALUES:] = grad_v
    # sequential (one parallel region less; a few ms at most): plain loops, as a top-level slice
    # assignment would become a parallel region of its own
    grads = np.empty((n_cams, n, GRAD_VALUES + dims))
    for cam in range(n_cams):
        for i in range(n):
            for col in range(GRAD_VALUES + dims):
                grads[cam, i, col] = 0.0
        for k in range(offsets[cam * tiles], offsets[(cam + 1) * tiles]):
            i = ids[k]
            for col in range(GRAD_VALUES + dims):
                grads[cam, i, col] += rows[k, col]
    return grads
