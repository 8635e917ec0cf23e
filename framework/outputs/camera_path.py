"""Novel-view camera paths: a closed loop through a rig's cameras in ring order, interpolated between
neighbours (slerp of rotations, lerp of centres and intrinsics)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.camera import Camera


def ring_order(cameras: Sequence[Camera]) -> list[Camera]:
    """``cameras`` sorted by azimuth around the ring they stand on, starting from ``cameras[0]``.

    The ring's axis is the normal of the plane best fitting the camera centres, pointing to the cameras'
    average up direction (−y in OpenCV axes), so the order runs counter-clockwise seen from above.
    Fewer than three cameras are returned as given.
    """
    cameras = list(cameras)
    if len(cameras) < 3:
        return cameras
    centres = np.stack([camera.center for camera in cameras])
    offsets = centres - centres.mean(axis=0)
    _, _, axes = np.linalg.svd(offsets)
    normal = axes[2]
    up = -np.mean([camera.R[1] for camera in cameras], axis=0)
    if normal @ up < 0:
        normal = -normal
    first = axes[0]
    second = np.cross(normal, first)
    azimuth = np.arctan2(offsets @ second, offsets @ first)
    order = np.argsort((azimuth - azimuth[0]) % (2 * np.pi), kind="stable")
    return [cameras[index] for index in order]


def interpolate_camera(a: Camera, b: Camera, u: float, name: str) -> Camera:
    """The camera ``u`` ∈ [0, 1] of the way from ``a`` to ``b``: rotation slerped, centre and K lerped;
    ``a``'s image size (``b`` must share it)."""
    from scipy.spatial.transform import Rotation, Slerp

    if (a.width, a.height) != (b.width, b.height):
        raise InputError(f"cameras {a.name!r} and {b.name!r} differ in image size; scale them to one size first")
    rotation = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([a.R, b.R])))([u]).as_matrix()[0]
    centre = (1 - u) * a.center + u * b.center
    K = (1 - u) * a.K + u * b.K
    return Camera(name, a.width, a.height, K, rotation, -rotation @ centre)


def camera_path(cameras: Sequence[Camera], frames_per_segment: int) -> list[Camera]:
    """A closed loop through ``cameras`` in ring order: ``frames_per_segment`` cameras from each camera
    towards the next (the last back to the first), so path camera ``i·frames_per_segment`` is the ring's
    i-th camera exactly. Every camera is first scaled to the first one's image size."""
    if frames_per_segment < 1:
        raise InputError(f"frames per segment must be ≥ 1, got {frames_per_segment}")
    if not cameras:
        raise InputError("a camera path needs at least one camera")
    width, height = cameras[0].width, cameras[0].height
    ring = [
        camera if (camera.width, camera.height) == (width, height) else camera.scaled(width / camera.width, height / camera.height)
        for camera in ring_order(cameras)
    ]
    path = []
    for i, start in enumerate(ring):
        end = ring[(i + 1) % len(ring)]
        for step in range(frames_per_segment):
            path.append(interpolate_camera(start, end, step / frames_per_segment, f"path_{len(path):04d}"))
    return path
