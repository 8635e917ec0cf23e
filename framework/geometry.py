"""Geometry of a camera rig: where the cameras look, and how big the scene is."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from .camera import Camera


def rig_center(cameras: Sequence[Camera]) -> np.ndarray:
    """The calibration centre: the point closest (least squares) to every camera's optical axis — the
    middle of the mat for a ring of cameras looking at it."""
    if len(cameras) < 2:
        raise ValueError("the rig centre needs at least two cameras")
    system = np.zeros((3, 3))
    rhs = np.zeros(3)
    for camera in cameras:
        axis = camera.R[2]  # the optical axis in world coordinates
        projector = np.eye(3) - np.outer(axis, axis)
        system += projector
        rhs += projector @ camera.center
    if np.linalg.cond(system) > 1e8:
        raise ValueError("the cameras' optical axes are parallel: the rig centre is undefined")
    return np.linalg.solve(system, rhs)


def rig_scale(cameras: Sequence[Camera], center: np.ndarray) -> float:
    """The scene scale in metres: the mean distance from the cameras to the rig centre (learning rates
    and densification thresholds are relative to it, as in 3DGS)."""
    return float(np.mean([np.linalg.norm(camera.center - center) for camera in cameras]))


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """[N, 4] (w, x, y, z) quaternions, normalised here, → [N, 3, 3] rotation matrices."""
    w, x, y, z = (quats / quats.norm(dim=-1, keepdim=True)).unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )
    return torch.stack(rows, dim=-1).reshape(-1, 3, 3)


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of [..., 4] (w, x, y, z) quaternions: the rotation ``b`` followed by ``a``."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack((
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ), dim=-1)


def quat_conjugate(quats: torch.Tensor) -> torch.Tensor:
    """The conjugate of [..., 4] (w, x, y, z) quaternions: the inverse rotation of unit quaternions."""
    return quats * quats.new_tensor([1.0, -1.0, -1.0, -1.0])
