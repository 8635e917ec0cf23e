"""EWA projection of 3D Gaussians into C cameras and their tile ranges, in plain differentiable PyTorch.

Steps 1–9 of "Projection" in docs/rendering.md, vectorised over cameras and Gaussians; shared by the torch
backends (the reference composites with it, a compiled backend may reuse it for its projection).
"""

from __future__ import annotations

import attrs
import torch

from mmcsplat.plugin_api.render_contract import LOW_PASS, NEAR_PLANE, SIGMA_EXTENT, TILE_SIZE, Gaussians, RenderCameras
from mmcsplat.scene.quaternions import quat_to_rotmat


@attrs.frozen(eq=False)
class Projection:
    """Per camera and Gaussian screen-space quantities ([C, N, ...]); entries of culled Gaussians
    (``radii == 0``) are finite placeholders with an empty tile range.

    means2d [C, N, 2] pixels (the means2d input already added); conics [C, N, 3] (a, b, c) of the inverse
    2D covariance; depths [C, N] camera-space z; radii [C, N] int32; tiles [C, N, 4] int64 (x0, x1, y0,
    y1), the half-open tile range covered; opacities [N] (after the sigmoid).
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    depths: torch.Tensor
    radii: torch.Tensor
    tiles: torch.Tensor
    opacities: torch.Tensor


def covariances_3d(quats: torch.Tensor, log_scales: torch.Tensor) -> torch.Tensor:
    """[N, 3, 3] world covariances Σ = R S Sᵀ Rᵀ."""
    m = quat_to_rotmat(quats) * torch.exp(log_scales)[:, None, :]  # R @ diag(s)
    return m @ m.transpose(-1, -2)


def screen_radii(cov2d: torch.Tensor) -> torch.Tensor:
    """[..., 2, 2] 2D covariances → float radius ceil(3·sqrt(λ₁)) (no gradient: radii are integers)."""
    cov2d = cov2d.detach()
    a, b, c = cov2d[..., 0, 0], cov2d[..., 0, 1], cov2d[..., 1, 1]
    mid = 0.5 * (a + c)
    lambda1 = mid + torch.sqrt(torch.clamp_min(mid * mid - (a * c - b * b), 0.1))
    return torch.ceil(SIGMA_EXTENT * torch.sqrt(lambda1))


def tile_ranges(means2d: torch.Tensor, radii: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """[..., 2] means and [...] float radii → [..., 4] int64 (x0, x1, y0, y1) half-open tile ranges, each
    clamped to the ceil(W/16) × ceil(H/16) grid (step 9 of docs/rendering.md)."""
    tiles_x = -(-width // TILE_SIZE)
    tiles_y = -(-height // TILE_SIZE)
    m = means2d.detach()
    mx, my = m[..., 0], m[..., 1]
    x0 = torch.floor((mx - radii) / TILE_SIZE).clamp(0, tiles_x)
    x1 = torch.floor((mx + radii + TILE_SIZE - 1) / TILE_SIZE).clamp(0, tiles_x)
    y0 = torch.floor((my - radii) / TILE_SIZE).clamp(0, tiles_y)
    y1 = torch.floor((my + radii + TILE_SIZE - 1) / TILE_SIZE).clamp(0, tiles_y)
    return torch.stack([x0, x1, y0, y1], dim=-1).long()


def project(gaussians: Gaussians, cameras: RenderCameras, means2d_offset: torch.Tensor) -> Projection:
    """Project every Gaussian into every camera; ``means2d_offset`` [C, N, 2] is added to the 2D means.

    Differentiable with respect to the Gaussian parameters and the offset. Culled Gaussians (behind the
    near plane, degenerate 2D covariance, covering no tile) get radius 0 and zero gradients.
    """
    dtype, device = gaussians.means.dtype, gaussians.means.device
    K = cameras.K.to(device=device, dtype=dtype)
    viewmats = cameras.viewmats.to(device=device, dtype=dtype)
    rot, trans = viewmats[:, :3, :3], viewmats[:, :3, 3]  # [C, 3, 3], [C, 3]

    p = torch.einsum("cij,nj->cni", rot, gaussians.means) + trans[:, None, :]  # [C, N, 3]
    z = p[..., 2]
    in_front = z >= NEAR_PLANE
    # Culled Gaussians get z = 1 so that nothing below divides by ~0: their gradients stay 0, not NaN.
    z = torch.where(in_front, z, torch.ones_like(z))
    x, y = p[..., 0], p[..., 1]

    sigma = covariances_3d(gaussians.quats, gaussians.log_scales)  # [N, 3, 3]
    cov_cam = rot[:, None] @ sigma[None] @ rot[:, None].transpose(-1, -2)  # [C, N, 3, 3]

    fx, fy, cx, cy = (v[:, None] for v in (K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]))
    tan_x, tan_y = cameras.width / (2 * fx), cameras.height / (2 * fy)
    # The 3DGS Jacobian clamp: far off-screen Gaussians are linearised at 1.3× the field of view.
    tx = z * torch.clamp(x / z, -(cx / fx + 0.3 * tan_x), (cameras.width - cx) / fx + 0.3 * tan_x)
    ty = z * torch.clamp(y / z, -(cy / fy + 0.3 * tan_y), (cameras.height - cy) / fy + 0.3 * tan_y)
    zero = torch.zeros_like(z)
    jac = torch.stack(
        [fx / z, zero, -fx * tx / (z * z), zero, fy / z, -fy * ty / (z * z)], dim=-1
    ).reshape(*z.shape, 2, 3)
    cov2d = jac @ cov_cam @ jac.transpose(-1, -2) + LOW_PASS * torch.eye(2, dtype=dtype, device=device)

    means2d = torch.stack([fx * x / z + cx, fy * y / z + cy], dim=-1) + means2d_offset
    a, b, c = cov2d[..., 0, 0], cov2d[..., 0, 1], cov2d[..., 1, 1]
    det = a * c - b * b
    radii = screen_radii(cov2d)
    # Absurd scales overflow: a non-finite determinant or radius is culled like a degenerate one.
    valid = in_front & (det > 0) & torch.isfinite(det) & torch.isfinite(radii)
    det = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c, -b, a], dim=-1) / det[..., None]

    radii = torch.where(valid, radii, torch.zeros_like(radii))
    tiles = tile_ranges(means2d, radii, cameras.width, cameras.height)
    valid = valid & (tiles[..., 1] > tiles[..., 0]) & (tiles[..., 3] > tiles[..., 2])
    tiles = torch.where(valid[..., None], tiles, torch.zeros_like(tiles))
    radii = torch.where(valid, radii, torch.zeros_like(radii)).to(torch.int32)
    return Projection(means2d, conics, p[..., 2], radii, tiles, torch.sigmoid(gaussians.opacity_logits))
