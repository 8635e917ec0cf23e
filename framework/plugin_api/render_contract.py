"""The renderer contract: Gaussians and cameras in, images and per-Gaussian screen statistics out.

Every renderer backend consumes and produces these classes; docs/rendering.md states the conventions
(pixel centres, culling, compositing). Inputs are checked here, once, for every backend.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import attrs
import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera, look_at

#: Rasterizer constants shared by every backend (the 3DGS conventions, docs/rendering.md).
TILE_SIZE = 16
LOW_PASS = 0.3  # px² added to the 2D covariance diagonal
SIGMA_EXTENT = 3.0  # screen radius = ceil(3 σ_max)
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
TRANSMITTANCE_MIN = 1e-4
NEAR_PLANE = 0.01  # metres; Gaussians whose centre is nearer (or behind) are culled
DEPTH_EPS = 1e-10  # expected depth = Σ wᵢ zᵢ / max(alpha, DEPTH_EPS)


@attrs.frozen(eq=False)
class Gaussians:
    """A set of N 3D Gaussians, as the optimiser holds them (unconstrained parameters).

    means [N, 3] metres; quats [N, 4] (w, x, y, z), not necessarily normalised; log_scales [N, 3];
    opacity_logits [N] (opacity = sigmoid); colors [N, 3] (already in [0, 1] space, used as given);
    features [N, F] extra channels composited like colour (e.g. the segmentation colour), F ≥ 0.
    """

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    opacity_logits: torch.Tensor
    colors: torch.Tensor
    features: torch.Tensor

    @property
    def count(self) -> int:
        return int(self.means.shape[0])

    @classmethod
    def from_linear(
        cls,
        means: torch.Tensor,
        quats: torch.Tensor,
        scales: torch.Tensor,
        opacities: torch.Tensor,
        colors: torch.Tensor,
        features: torch.Tensor | None = None,
    ) -> Gaussians:
        """Build from linear scales and opacities in (0, 1) (as benchmark scenes are described)."""
        if features is None:
            features = means.new_zeros((means.shape[0], 0))
        return cls(means, quats, torch.log(scales), torch.logit(opacities), colors, features)


@attrs.frozen(eq=False)
class RenderCameras:
    """C pinhole cameras sharing one image size: K [C, 3, 3] and world-to-camera viewmats [C, 4, 4]
    (OpenCV axes). Pixel (u, v) has its centre at the continuous coordinate (u, v), as in OpenCV, so a
    calibration's K applies unchanged."""

    K: torch.Tensor
    viewmats: torch.Tensor
    width: int
    height: int

    @property
    def count(self) -> int:
        return int(self.K.shape[0])

    def select(self, indices: Sequence[int]) -> RenderCameras:
        """The cameras at ``indices``, as a new batch."""
        index = torch.as_tensor(list(indices), dtype=torch.long)
        return RenderCameras(self.K[index], self.viewmats[index], self.width, self.height)

    @classmethod
    def from_cameras(cls, cameras: Sequence[Camera], dtype: torch.dtype = torch.float32) -> RenderCameras:
        """Stack calibrated (undistorted) cameras of one image size; the renderers are pinhole-only."""
        sizes = {(camera.width, camera.height) for camera in cameras}
        if len(sizes) != 1:
            raise RenderInputError(f"cameras must share one image size to render together, got {sorted(sizes)}")
        distorted = [camera.name for camera in cameras if camera.is_distorted]
        if distorted:
            raise RenderInputError(f"cameras {distorted} have lens distortion; ingest undistorts frames first")
        ((width, height),) = sizes
        K = torch.as_tensor(np.stack([camera.K for camera in cameras]), dtype=dtype)
        viewmats = torch.as_tensor(np.stack([camera.world_to_camera for camera in cameras]), dtype=dtype)
        return cls(K, viewmats, width, height)

    @classmethod
    def each(cls, cameras: Sequence[Camera], dtype: torch.dtype = torch.float32) -> tuple[RenderCameras, ...]:
        """One single-camera batch per camera, so that a rig whose cameras differ in size (real rigs often
        do: 1080 and 1088 rows) renders camera by camera, as training does anyway."""
        return tuple(cls.from_cameras([camera], dtype) for camera in cameras)


@attrs.frozen(eq=False)
class RenderOutput:
    """What a renderer returns for C cameras.

    rgb [C, H, W, 3] (composited over the background), features [C, H, W, F] (no background), depth
    [C, H, W] (expected depth: Σ wᵢ zᵢ / max(alpha, 1e-10), 0 where nothing was drawn), alpha [C, H, W],
    radii [C, N] integer screen radii in pixels (0 = culled), and means2d [C, N, 2], a tensor on the path
    of the projected 2D means (the reference backends add a zero input there; gsplat returns the means
    themselves): only its shape and its gradient are contract — after backward, ``means2d.grad`` is the
    per-Gaussian screen-space gradient
    densification accumulates (``None`` when the caller did not request gradients).
    """

    rgb: torch.Tensor
    features: torch.Tensor
    depth: torch.Tensor
    alpha: torch.Tensor
    radii: torch.Tensor
    means2d: torch.Tensor

    @property
    def visible(self) -> torch.Tensor:
        """[C, N] bool: the Gaussian touched at least one tile of the camera."""
        return self.radii > 0


class RenderInputError(InputError):
    """Bad renderer input: wrong shape, non-finite values, an impossible camera."""


def all_finite(tensor: torch.Tensor) -> bool:
    """Whether every element of floating-point ``tensor`` is finite: its sum in float64 is (one NaN makes it
    NaN, an infinity infinite or NaN, and float32 values cannot overflow it), a third of the cost of
    testing each element on a training step's images."""
    return bool(torch.isfinite(tensor.detach().sum(dtype=torch.float64)))


def validate_render_inputs(gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None) -> None:
    """Raise :class:`RenderInputError` naming the offending input; every backend calls this first."""
    n = gaussians.means.shape[0] if gaussians.means.dim() == 2 else -1
    expected = {
        "means": (n, 3),
        "quats": (n, 4),
        "log_scales": (n, 3),
        "opacity_logits": (n,),
        "colors": (n, 3),
    }
    for field, shape in expected.items():
        value = getattr(gaussians, field)
        if not isinstance(value, torch.Tensor):
            raise RenderInputError(f"Gaussians.{field} must be a torch.Tensor, got {type(value).__name__}")
        if tuple(value.shape) != shape or n < 0:
            raise RenderInputError(f"Gaussians.{field} must have shape {shape}, got {tuple(value.shape)}")
    features = gaussians.features
    if not isinstance(features, torch.Tensor) or features.dim() != 2 or features.shape[0] != n:
        raise RenderInputError(f"Gaussians.features must have shape ({n}, F), got {tuple(getattr(features, 'shape', ()))}")
    for field in (*expected, "features"):
        value = getattr(gaussians, field)
        if not value.is_floating_point():
            raise RenderInputError(f"Gaussians.{field} must be floating point, got {value.dtype}")
        if not all_finite(value):
            bad = int((~torch.isfinite(value.detach())).any(dim=-1).sum()) if value.dim() > 1 else int((~torch.isfinite(value.detach())).sum())
            raise RenderInputError(f"Gaussians.{field} has non-finite values in {bad} Gaussian(s)")
    if n and (gaussians.quats.detach().norm(dim=-1) == 0).any():
        raise RenderInputError("Gaussians.quats has zero-length quaternions")
    c = cameras.K.shape[0] if cameras.K.dim() == 3 else -1
    if c < 1 or tuple(cameras.K.shape) != (c, 3, 3):
        raise RenderInputError(f"RenderCameras.K must have shape (C, 3, 3) with C ≥ 1, got {tuple(cameras.K.shape)}")
    if tuple(cameras.viewmats.shape) != (c, 4, 4):
        raise RenderInputError(f"RenderCameras.viewmats must have shape ({c}, 4, 4), got {tuple(cameras.viewmats.shape)}")
    for field in ("K", "viewmats"):
        if not all_finite(getattr(cameras, field)):
            raise RenderInputError(f"RenderCameras.{field} is not finite")
    if (cameras.K[:, 0, 0] <= 0).any() or (cameras.K[:, 1, 1] <= 0).any():
        raise RenderInputError("RenderCameras.K must have positive focal lengths")
    if int(cameras.width) < 1 or int(cameras.height) < 1:
        raise RenderInputError(f"image size must be positive, got {cameras.width}×{cameras.height}")
    if background is not None:
        if tuple(background.shape) not in ((3,), (c, 3)):
            raise RenderInputError(f"background must have shape (3,) or ({c}, 3), got {tuple(background.shape)}")
        if not all_finite(background):
            raise RenderInputError("background is not finite")


def composite(render: RenderOutput, index: int, backdrop: torch.Tensor) -> torch.Tensor:
    """Camera ``index`` of ``render`` (rendered over black) over ``backdrop``: [H, W, 3]."""
    return render.rgb[index] + (1.0 - render.alpha[index])[..., None] * backdrop


def viewmat_looking_at(centre: Sequence[float], target: Sequence[float] = (0.0, 0.0, 0.0)) -> torch.Tensor:
    """[4, 4] float32 world-to-camera matrix of a camera at ``centre`` looking at ``target`` (z up):
    rotation :func:`~mmcsplat.scene.camera.look_at`, translation −R·c."""
    rotation = torch.as_tensor(look_at(centre, target, dtype=np.float32))
    viewmat = torch.eye(4)
    viewmat[:3, :3] = rotation
    viewmat[:3, 3] = -rotation @ torch.tensor(centre, dtype=torch.float32)
    return viewmat


def gaussians_from_params(params: Mapping[str, torch.Tensor]) -> Gaussians:
    """Renderable Gaussians from stored parameters (colour and segmentation logits through a sigmoid)."""
    return Gaussians(
        params["means"],
        params["quats"],
        params["log_scales"],
        params["opacity_logits"],
        torch.sigmoid(params["color_logits"]),
        torch.sigmoid(params["seg_logits"]),
    )
