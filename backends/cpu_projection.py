"""Numba EWA projection of the ``torch-cpu`` renderer, forward and hand-written backward.

Steps 1–9 of "Projection" in docs/rendering.md, per Gaussian and camera, in float64; the same maths as
:func:`mmcsplat.backends.torch_projection.project` (the reference's), compiled because the vectorised
torch version costs more than the whole tile compositing on the bench scenes (about 25 ms forward and
50 ms backward on scene B, against about 1 ms here). The 2D covariance is built as (J·W·R·S)(J·W·R·S)ᵀ,
which is J·W·Σ·Wᵀ·Jᵀ with Σ = R·S·Sᵀ·Rᵀ.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from mmcsplat.plugin_api.render_contract import LOW_PASS, NEAR_PLANE, SIGMA_EXTENT, TILE_SIZE

_PARALLEL = {"parallel": True, "cache": True, "fastmath": False, "nogil": True}
_INLINE = {"cache": True, "fastmath": False, "inline": "always"}
_HELPER = {"cache": True, "fastmath": False}
_MAX_RADIUS = 2.0**31 - 1  # radii are int32
_BLOCK = 256  # Gaussians per parallel work item: the scratch array is allocated once per block
_SCRATCH_ROWS = 15  # 3-vectors: R, R·S, rows of J·W and of (J·W·R·S)ᵀ, and the backward's gradients


@njit(**_INLINE)
def _rotation_scale(quats, log_scales, i, rot, rs):
    """rot ← R(q/|q|), rs ← R·diag(exp(log_scales)); returns |q| and the normalised (w, x, y, z)."""
    norm = math.sqrt(quats[i, 0] ** 2 + quats[i, 1] ** 2 + quats[i, 2] ** 2 + quats[i, 3] ** 2)
    w, x, y, z = quats[i, 0] / norm, quats[i, 1] / norm, quats[i, 2] / norm, quats[i, 3] / norm
    rot[0, 0], rot[0, 1], rot[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    rot[1, 0], rot[1, 1], rot[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    rot[2, 0], rot[2, 1], rot[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    for k in range(3):
        scale = math.exp(log_scales[i, k])
        for j in range(3):
            rs[j, k] = rot[j, k] * scale
    return norm, w, x, y, z


@njit(**_INLINE)
def _limits(size, f, centre):
    """The 3DGS clamp of x/z (or y/z) in the EWA Jacobian: the field of view widened by 30 %."""
    tan_half = size / (2.0 * f)
    return -(centre / f + 0.3 * tan_half), (size - centre) / f + 0.3 * tan_half


@njit(**_INLINE)
def _screen(means, i, view, intr, cam, width, height, rs, t0, t1, a0, a1):
    """Camera point p, clamped tx, ty, the rows t0, t1 of J·W and a0 = (J·W·R·S)ᵀ row 0, a1 = row 1.

    Returns (px, py, pz, tx, ty, clamped_x, clamped_y, fx, fy, cx, cy); rows are left unset when
    pz < NEAR_PLANE."""
    mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
    px = view[cam, 0, 0] * mx + view[cam, 0, 1] * my + view[cam, 0, 2] * mz + view[cam, 0, 3]
    py = view[cam, 1, 0] * mx + view[cam, 1, 1] * my + view[cam, 1, 2] * mz + view[cam, 1, 3]
    pz = view[cam, 2, 0] * mx + view[cam, 2, 1] * my + view[cam, 2, 2] * mz + view[cam, 2, 3]
    fx, fy, cx, cy = intr[cam, 0, 0], intr[cam, 1, 1], intr[cam, 0, 2], intr[cam, 1, 2]
    if pz < NEAR_PLANE:
        return px, py, pz, 0.0, 0.0, False, False, fx, fy, cx, cy
    lo_x, hi_x = _limits(width, fx, cx)
    lo_y, hi_y = _limits(height, fy, cy)
    xz, yz = px / pz, py / pz
    tx = pz * min(max(xz, lo_x), hi_x)
    ty = pz * min(max(yz, lo_y), hi_y)
    j00, j02 = fx / pz, -fx * tx / (pz * pz)
    j11, j12 = fy / pz, -fy * ty / (pz * pz)
    for k in range(3):
        t0[k] = j00 * view[cam, 0, k] + j02 * view[cam, 2, k]
        t1[k] = j11 * view[cam, 1, k] + j12 * view[cam, 2, k]
    for k in range(3):
        a0[k] = t0[0] * rs[0, k] + t0[1] * rs[1, k] + t0[2] * rs[2, k]
        a1[k] = t1[0] * rs[0, k] + t1[1] * rs[1, k] + t1[2] * rs[2, k]
    clamped_x = xz < lo_x or xz > hi_x
    clamped_y = yz < lo_y or yz > hi_y
    return px, py, pz, tx, ty, clamped_x, clamped_y, fx, fy, cx, cy


@njit(**_HELPER)
def _project_gaussian(i, means, quats, log_scales, viewmats, intrinsics, width, height, scratch,
                      means2d, conics, depths, radii, tiles):
    """Project Gaussian i into every camera (writes row i of the outputs of :func:`project_forward`)."""
    rot, rs, t0, t1, a0, a1 = scratch[0:3], scratch[3:6], scratch[6], scratch[7], scratch[8], scratch[9]
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    tiles_y = (height + TILE_SIZE - 1) // TILE_SIZE
    _rotation_scale(quats, log_scales, i, rot, rs)
    for cam in range(viewmats.shape[0]):
        px, py, pz, _, _, _, _, fx, fy, cx, cy = _screen(means, i, viewmats, intrinsics, cam, width, height, rs, t0, t1, a0, a1)
        depths[cam, i] = pz
        radii[cam, i] = 0  # culled until proven otherwise
        tiles[cam, i, 0] = tiles[cam, i, 1] = tiles[cam, i, 2] = tiles[cam, i, 3] = 0
        means2d[cam, i, 0] = means2d[cam, i, 1] = 0.0
        conics[cam, i, 0] = conics[cam, i, 1] = conics[cam, i, 2] = 0.0
        if pz < NEAR_PLANE:
            continue
        sxx = a0[0] * a0[0] + a0[1] * a0[1] + a0[2] * a0[2] + LOW_PASS
        sxy = a0[0] * a1[0] + a0[1] * a1[1] + a0[2] * a1[2]
        syy = a1[0] * a1[0] + a1[1] * a1[1] + a1[2] * a1[2] + LOW_PASS
        det = sxx * syy - sxy * sxy
        if not (det > 0.0 and math.isfinite(det)):
            continue
        mid = 0.5 * (sxx + syy)
        radius = math.ceil(SIGMA_EXTENT * math.sqrt(mid + math.sqrt(max(0.1, mid * mid - det))))
        if not math.isfinite(radius):
            continue
        radius = min(radius, _MAX_RADIUS)
        u, v = fx * px / pz + cx, fy * py / pz + cy
        x0 = min(max(math.floor((u - radius) / TILE_SIZE), 0.0), tiles_x)
        x1 = min(max(math.floor((u + radius + TILE_SIZE - 1) / TILE_SIZE), 0.0), tiles_x)
        y0 = min(max(math.floor((v - radius) / TILE_SIZE), 0.0), tiles_y)
        y1 = min(max(math.floor((v + radius + TILE_SIZE - 1) / TILE_SIZE), 0.0), tiles_y)
        if x1 <= x0 or y1 <= y0:
            continue
        radii[cam, i] = int(radius)
        tiles[cam, i, 0], tiles[cam, i, 1], tiles[cam, i, 2], tiles[cam, i, 3] = int(x0), int(x1), int(y0), int(y1)
        means2d[cam, i, 0], means2d[cam, i, 1] = u, v
        conics[cam, i, 0], conics[cam, i, 1], conics[cam, i, 2] = syy / det, -sxy / det, sxx / det


@njit(**_PARALLEL)
def project_forward(means, quats, log_scales, viewmats, intrinsics, width, height):
    """Project N Gaussians into C cameras (float64 arrays; intrinsics [C, 3, 3], viewmats [C, 4, 4]).

    Returns means2d [C, N, 2], conics [C, N, 3] (a, b, c), depths [C, N] (camera z, also of culled
    Gaussians), radii [C, N] int32 and tiles [C, N, 4] int64 (x0, x1, y0, y1). Culled Gaussians (nearer
    than the near plane, non-positive or non-finite determinant, no tile) have radius 0, an empty tile
    range and zero means2d and conic.
    """
    n_cams, n = viewmats.shape[0], means.shape[0]
    # np.empty, filled by _project_gaussian: np.zeros would be a parallel region (a fork-join) of its own
    means2d = np.empty((n_cams, n, 2))
    conics = np.empty((n_cams, n, 3))
    depths = np.empty((n_cams, n))
    radii = np.empty((n_cams, n), np.int32)
    tiles = np.empty((n_cams, n, 4), np.int64)
    for block in prange((n + _BLOCK - 1) // _BLOCK):
        scratch = np.empty((_SCRATCH_ROWS, 3))
        for i in range(block * _BLOCK, min(n, (block + 1) * _BLOCK)):
            _project_gaussian(i, means, quats, log_scales, viewmats, intrinsics, width, height, scratch,
                              means2d, conics, depths, radii, tiles)
    return means2d, conics, depths, radii, tiles


@njit(**_HELPER)
def _backward_gaussian(i, means, quats, log_scales, viewmats, intrinsics, width, height, radii, scratch,
                       grad_means2d, grad_conics, grad_depths, g_means, g_quats, g_log_scales):
    """Row i of the gradients of :func:`project_backward`, summed over the cameras."""
    rot, rs, t0, t1, a0, a1 = scratch[0:3], scratch[3:6], scratch[6], scratch[7], scratch[8], scratch[9]
    g_rs, g_a0, g_a1 = scratch[10:13], scratch[13], scratch[14]
    n_cams = viewmats.shape[0]
    norm, w, x, y, z = _rotation_scale(quats, log_scales, i, rot, rs)
    g_rs[:] = 0.0
    g_means[i] = 0.0
    for cam in range(n_cams):
        if radii[cam, i] == 0:
            continue
        px, py, pz, tx, ty, clamped_x, clamped_y, fx, fy, _, _ = _screen(
            means, i, viewmats, intrinsics, cam, width, height, rs, t0, t1, a0, a1
        )
        sxx = a0[0] * a0[0] + a0[1] * a0[1] + a0[2] * a0[2] + LOW_PASS
        sxy = a0[0] * a1[0] + a0[1] * a1[1] + a0[2] * a1[2]
        syy = a1[0] * a1[0] + a1[1] * a1[1] + a1[2] * a1[2] + LOW_PASS
        inv = 1.0 / (sxx * syy - sxy * sxy)
        # conic = (syy, −sxy, sxx) / det
        ga, gb, gc = grad_conics[cam, i, 0], grad_conics[cam, i, 1], grad_conics[cam, i, 2]
        g_det = -(ga * syy - gb * sxy + gc * sxx) * inv * inv
        g_sxx = gc * inv + g_det * syy
        g_syy = ga * inv + g_det * sxx
        g_sxy = -gb * inv - 2.0 * g_det * sxy
        # sxx = a0·a0, sxy = a0·a1, syy = a1·a1 with a0 = (R S)ᵀ t0, a1 = (R S)ᵀ t1
        for k in range(3):
            g_a0[k] = 2.0 * g_sxx * a0[k] + g_sxy * a1[k]
            g_a1[k] = 2.0 * g_syy * a1[k] + g_sxy * a0[k]
        g00 = g02 = g11 = g12 = 0.0
        for j in range(3):
            g_t0 = rs[j, 0] * g_a0[0] + rs[j, 1] * g_a0[1] + rs[j, 2] * g_a0[2]
            g_t1 = rs[j, 0] * g_a1[0] + rs[j, 1] * g_a1[1] + rs[j, 2] * g_a1[2]
            for k in range(3):
                g_rs[j, k] += t0[j] * g_a0[k] + t1[j] * g_a1[k]
            g00 += g_t0 * viewmats[cam, 0, j]
            g02 += g_t0 * viewmats[cam, 2, j]
            g11 += g_t1 * viewmats[cam, 1, j]
            g12 += g_t1 * viewmats[cam, 2, j]
        # means2d = (fx·px/pz + cx, fy·py/pz + cy); depth = pz; J = [[fx/z, 0, −fx·tx/z²], [0, fy/z, −fy·ty/z²]]
        gu, gv = grad_means2d[cam, i, 0], grad_means2d[cam, i, 1]
        z2 = pz * pz
        g_px = gu * fx / pz
        g_py = gv * fy / pz
        g_pz = grad_depths[cam, i] - (gu * fx * px + gv * fy * py) / z2 - (fx * g00 + fy * g11) / z2
        g_pz += 2.0 * (fx * tx * g02 + fy * ty * g12) / (z2 * pz)
        g_tx, g_ty = -fx * g02 / z2, -fy * g12 / z2
        if clamped_x:  # tx = z · limit
            g_pz += g_tx * tx / pz
        else:  # tx = px
            g_px += g_tx
        if clamped_y:
            g_pz += g_ty * ty / pz
        else:
            g_py += g_ty
        for k in range(3):
            g_means[i, k] += viewmats[cam, 0, k] * g_px + viewmats[cam, 1, k] * g_py + viewmats[cam, 2, k] * g_pz
    # rs = R·diag(s), s = exp(log_scales)
    for k in range(3):
        scale = math.exp(log_scales[i, k])
        g_log_scales[i, k] = scale * (g_rs[0, k] * rot[0, k] + g_rs[1, k] * rot[1, k] + g_rs[2, k] * rot[2, k])
        for j in range(3):
            g_rs[j, k] *= scale  # now d loss / d R
    g = g_rs
    gw = 2 * (-z * g[0, 1] + y * g[0, 2] + z * g[1, 0] - x * g[1, 2] - y * g[2, 0] + x * g[2, 1])
    gx = 2 * (y * g[0, 1] + z * g[0, 2] + y * g[1, 0] - 2 * x * g[1, 1] - w * g[1, 2] + z * g[2, 0] + w * g[2, 1] - 2 * x * g[2, 2])
    gy = 2 * (-2 * y * g[0, 0] + x * g[0, 1] + w * g[0, 2] + x * g[1, 0] + z * g[1, 2] - w * g[2, 0] + z * g[2, 1] - 2 * y * g[2, 2])
    gz = 2 * (-2 * z * g[0, 0] - w * g[0, 1] + x * g[0, 2] + w * g[1, 0] - 2 * z * g[1, 1] + y * g[1, 2] + x * g[2, 0] + y * g[2, 1])
    # q̂ = q / |q|: d loss / d q = (g − q̂ (q̂·g)) / |q|
    dot = w * gw + x * gx + y * gy + z * gz
    g_quats[i, 0] = (gw - w * dot) / norm
    g_quats[i, 1] = (gx - x * dot) / norm
    g_quats[i, 2] = (gy - y * dot) / norm
    g_quats[i, 3] = (gz - z * dot) / norm


@njit(**_PARALLEL)
def project_backward(means, quats, log_scales, viewmats, intrinsics, width, height, radii, grad_means2d, grad_conics, grad_depths):
    """Gradients of :func:`project_forward`'s means2d, conics and depths with respect to means [N, 3],
    quats [N, 4] and log_scales [N, 3]; culled Gaussians (radius 0) pass nothing, clamps pass nothing
    where they clamp (as autograd through the reference)."""
    n = means.shape[0]
    g_means = np.empty((n, 3))  # filled by _backward_gaussian
    g_quats = np.empty((n, 4))
    g_log_scales = np.empty((n, 3))
    for block in prange((n + _BLOCK - 1) // _BLOCK):
        scratch = np.empty((_SCRATCH_ROWS, 3))
        for i in range(block * _BLOCK, min(n, (block + 1) * _BLOCK)):
            _backward_gaussian(i, means, quats, log_scales, viewmats, intrinsics, width, height, radii, scratch,
                               grad_means2d, grad_conics, grad_depths, g_means, g_quats, g_log_scales)
    return g_means, g_quats, g_log_scales
