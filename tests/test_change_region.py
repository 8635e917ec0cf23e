"""The region a ``parallax`` mask may cover: the convex hull of the voxels the cameras agree changed over
the sequence (plugins/segmenters/change_region.py), on small hand-made scenes."""

from __future__ import annotations

import numpy as np

from mmcsplat.plugins.segmenters.change_region import changed, hull_masks, main_pieces, moving_voxels
from mmcsplat.scene.camera import Camera, look_at


def _ring(count: int = 4, size: int = 64) -> list[Camera]:
    """``count`` pinhole cameras 2 m from the origin, 1.5 m up, looking at (0, 0, 0.5)."""
    cameras = []
    for i in range(count):
        angle = 2 * np.pi * i / count
        centre = np.array([2 * np.cos(angle), 2 * np.sin(angle), 1.5])
        R = look_at(centre, [0.0, 0.0, 0.5])
        K = np.array([[60.0, 0, (size - 1) / 2], [0, 60.0, (size - 1) / 2], [0, 0, 1]])
        cameras.append(Camera(f"cam_{i}", size, size, K, R, -R @ centre))
    return cameras


def test_changed_pixels_leave_out_single_pixel_specks():
    median = np.full((20, 20, 3), 100, np.uint8)
    image = median.copy()
    image[2, 2] = 200  # a speck
    image[10:14, 10:14, 1] = 130  # a 4 × 4 patch changed in one channel
    result = changed(image, median, 20.0)
    patch = np.zeros_like(result)
    patch[10:14, 10:14] = True
    # The opening's disk rounds the patch's corners off; nothing outside the patch changed.
    assert not result[2, 2] and result[11:13, 10:14].all() and result[10:14, 11:13].all() and not (result & ~patch).any()
    assert not changed(image, median, 40.0).any()  # 30 grey levels is under a 40 threshold


def test_main_pieces_keep_the_large_pieces_and_drop_specks():
    basis, size = np.eye(3), 0.1
    big = np.stack(np.meshgrid(*[np.arange(5) * size] * 3, indexing="ij"), axis=-1).reshape(-1, 3)  # 125 voxels
    leg = big[:20] + [2.0, 0, 0]  # 20 voxels, apart from it: at least a tenth of the largest
    speck = np.array([[0.0, 2.0, 0.0]])
    keep = main_pieces(np.concatenate([big, leg, speck]), basis, size)
    assert keep[:145].all() and not keep[145]


def test_moving_voxels_are_those_the_cameras_seeing_them_agree_changed():
    cameras = _ring()
    moving = np.array([[0.0, 0.0, 0.5]])
    still = np.array([[0.5, 0.5, 0.2]])
    ever = []
    for camera in cameras:
        mask = np.zeros((camera.height, camera.width), bool)
        u, v = np.round(camera.project(moving)[0]).astype(int)
        mask[v - 1 : v + 2, u - 1 : u + 2] = True
        ever.append(mask)
    assert moving_voxels(np.concatenate([moving, still]), cameras, ever, 0.8).tolist() == [True, False]
    ever[0][:] = False  # one camera in four disagrees: under a 0.8 agreement, the voxel goes
    assert not moving_voxels(moving, cameras, ever, 0.8)[0] and moving_voxels(moving, cameras, ever, 0.7)[0]


def test_hull_masks_hold_the_points_and_what_lies_between_them_grown_by_the_margin():
    cameras = _ring()
    ends = np.array([[-0.3, 0.0, 0.5], [0.3, 0.0, 0.5]])  # two moving hands; the still trunk between them
    between, beyond = np.array([[0.0, 0.0, 0.5]]), np.array([[0.0, 0.0, 1.2]])
    plain, grown = hull_masks(ends, cameras, 0.0), hull_masks(ends, cameras, 0.1)
    for camera, mask, wide in zip(cameras, plain, grown, strict=True):
        for point, inside in ((between, True), (beyond, False)):
            u, v = np.round(camera.project(point)[0]).astype(int)
            assert wide[v, u] == inside
        assert wide.sum() > mask.sum() and (wide | mask).sum() == wide.sum()
