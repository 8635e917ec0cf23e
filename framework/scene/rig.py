"""Geometry of a camera rig: where the cameras look, and how big the scene is."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera


def rig_center(cameras: Sequence[Camera]) -> np.ndarray:
    """The calibration centre: the point closest (least squares) to every camera's optical axis — the
    middle of the mat for a ring of cameras looking at it."""
    if len(cameras) < 2:
        raise InputError("the rig centre needs at least two cameras")
    system = np.zeros((3, 3))
    rhs = np.zeros(3)
    for camera in cameras:
        axis = camera.R[2]  # the optical axis in world coordinates
        projector = np.eye(3) - np.outer(axis, axis)
        system += projector
        rhs += projector @ camera.center
    if np.linalg.cond(system) > 1e8:
        raise InputError("the cameras' optical axes are parallel: the rig centre is undefined")
    return np.linalg.solve(system, rhs)


def rig_scale(cameras: Sequence[Camera], center: np.ndarray) -> float:
    """The scene scale in metres: the mean distance from the cameras to the rig centre (learning rates
    and densification thresholds are relative to it, as in 3DGS)."""
    return float(np.mean([np.linalg.norm(camera.center - center) for camera in cameras]))
