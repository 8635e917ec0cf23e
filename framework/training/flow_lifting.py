"""2D optical flow lifted to 3D displacements of points seen by several calibrated cameras.

Each camera c that sees point X gives the flow f_c at X's projection π_c(X): the point moved by d with
π_c(X + d) ≈ π_c(X) + f_c. Linearised at X (J_c, the 2×3 Jacobian of the pinhole projection), that is
J_c d = f_c, two equations per camera; d is their least-squares solution weighted by w_c (flow confidence ×
the point's visibility in c), refined by a few Gauss–Newton steps that relinearise at X + d so that a large
exact motion is recovered exactly. A point needs two cameras with weight and a well-conditioned normal
matrix (two views far enough apart to fix depth); the others are not lifted and keep whatever prediction
the caller falls back to.
"""

from __future__ import annotations

from collections.abc import Sequence

import attrs
import numpy as np
import torch

from mmcsplat.scene.camera import Camera

#: A camera whose weight for a point is at most this says nothing about it.
MIN_WEIGHT = 1e-3
#: Cameras with weight a point needs to be lifted.
MIN_CAMERAS = 2
#: Largest ratio of the normal matrix's eigenvalues accepted: past it the views are too close to fix depth
#: (two equally weighted cameras 3° apart reach ~1e3).
MAX_CONDITION = 1e3
#: Gauss–Newton steps after the linear solution.
REFINEMENTS = 3


@attrs.frozen(eq=False)
class LiftedMotion:
    """``displacement`` [N, 3] float32 metres (zero where not lifted) and ``lifted`` [N] bool: the points with
    enough well-placed cameras."""

    displacement: torch.Tensor
    lifted: torch.Tensor

    @property
    def fallbacks(self) -> int:
        """How many points were not lifted."""
        return int((~self.lifted).sum())


def camera_matrices(cameras: Sequence[Camera]) -> tuple[torch.Tensor, torch.Tensor]:
    """K [C, 3, 3] and world-to-camera [C, 4, 4], float64."""
    K = torch.as_tensor(np.stack([camera.K for camera in cameras]), dtype=torch.float64)
    viewmats = torch.as_tensor(np.stack([camera.world_to_camera for camera in cameras]), dtype=torch.float64)
    return K, viewmats


def project(points: torch.Tensor, K: torch.Tensor, viewmats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pixels [C, N, 2], depths [C, N] and Jacobians ∂pixel/∂point [C, N, 2, 3] of ``points`` [N, 3] in each
    camera (OpenCV pinhole, pixel centres at integers)."""
    rotation, translation = viewmats[:, :3, :3], viewmats[:, :3, 3]
    in_camera = torch.einsum("cij,nj->cni", rotation, points) + translation[:, None, :]
    homogeneous = torch.einsum("cij,cnj->cni", K, in_camera)
    depth = homogeneous[..., 2]
    pixels = homogeneous[..., :2] / depth[..., None]
    # ∂(p_k / p_2)/∂x_cam = (K_k − pixel_k K_2) / p_2, then through the rotation to world axes.
    rows = (K[:, None, :2, :] - pixels[..., None] * K[:, None, 2:3, :]) / depth[..., None, None]
    return pixels, depth, rows @ rotation[:, None]


def lift_flow(points: torch.Tensor, cameras: Sequence[Camera], flows: torch.Tensor, weights: torch.Tensor) -> LiftedMotion:
    """The displacements of ``points`` [N, 3] that best explain ``flows`` [C, N, 2] (pixels, each camera's
    flow at the point's projection) weighted by ``weights`` [C, N] ≥ 0 (module docstring). Points behind a
    camera get no weight from it."""
    K, viewmats = camera_matrices(cameras)
    points = points.detach().to(torch.float64)
    pixels, depth, jacobians = project(points, K, viewmats)
    targets = pixels + flows.to(torch.float64)
    weights = torch.where(depth > 0, weights.to(torch.float64).clamp_min(0), 0.0)
    weights = torch.where(weights > MIN_WEIGHT, weights, 0.0)
    normal = torch.einsum("cn,cnki,cnkj->nij", weights, jacobians, jacobians)
    eigenvalues = torch.linalg.eigvalsh(normal)
    lifted = ((weights > 0).sum(0) >= MIN_CAMERAS) & (eigenvalues[:, 0] > eigenvalues[:, 2] / MAX_CONDITION)
    identity = torch.eye(3, dtype=torch.float64)
    displacement = torch.zeros_like(points)
    for _ in range(1 + REFINEMENTS):
        if displacement.abs().sum() > 0:
            pixels, _, jacobians = project(points + displacement, K, viewmats)
            normal = torch.einsum("cn,cnki,cnkj->nij", weights, jacobians, jacobians)
        residual = targets - pixels
        rhs = torch.einsum("cn,cnki,cnk->ni", weights, jacobians, residual)
        safe = torch.where(lifted[:, None, None], normal, identity)
        step = torch.linalg.solve(safe, rhs[..., None])[..., 0]
        displacement = displacement + torch.where(lifted[:, None], step, 0.0)
    return LiftedMotion(displacement.to(torch.float32), lifted)


def sample_field(field: np.ndarray, pixels: torch.Tensor) -> torch.Tensor:
    """Bilinear samples [N, K] of ``field`` [H, W, K] (or [H, W] → [N, 1]) at ``pixels`` [N, 2] (u, v); zero
    outside the image."""
    values = torch.as_tensor(np.asarray(field, dtype=np.float32))
    if values.dim() == 2:
        values = values[..., None]
    height, width = values.shape[:2]
    scale = torch.tensor([2.0 / max(width - 1, 1), 2.0 / max(height - 1, 1)])
    grid = (pixels.to(torch.float32) * scale - 1.0)[None, None]
    sampled = torch.nn.functional.grid_sample(values.permute(2, 0, 1)[None], grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    return sampled[0, :, 0].T
