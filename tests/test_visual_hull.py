"""Pixel rays and the mask agreement of :mod:`mmcsplat.analysis.visual_hull`, on a sphere's exact silhouettes
(computed here, no rendering)."""

from __future__ import annotations

import attrs
import numpy as np
from fitting_scene import ring_camera

from mmcsplat.analysis.visual_hull import mask_agreement
from mmcsplat.scene.visual_hull import pixel_rays
from mmcsplat.studies.sessions import perturbed

RADIUS = 0.1


def sphere_mask(camera) -> np.ndarray:
    """[H, W] bool: the pixels whose ray passes within RADIUS of the origin (the sphere's silhouette)."""
    rows, cols = np.mgrid[: camera.height, : camera.width]
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
    near, far = pixel_rays(camera, pixels, np.array([1.0, 2.0])).transpose(1, 0, 2)
    direction = (far - near) / np.linalg.norm(far - near, axis=1, keepdims=True)
    closest = near - np.sum(near * direction, axis=1, keepdims=True) * direction
    return (np.linalg.norm(closest, axis=1) <= RADIUS).reshape(camera.height, camera.width)


def test_pixel_rays_project_back_to_their_pixels():
    camera = ring_camera("c", 0.4)
    distorted = attrs.evolve(camera, distortion=[0.05, -0.02, 0.001, 0.0005])
    pixels = np.array([[0.0, 0.0], [20.5, 17.0], [47.0, 35.0]])
    for lens in (camera, distorted):
        points = pixel_rays(lens, pixels, np.array([0.3, 1.5, 4.0]))
        assert points.shape == (3, 3, 3)
        np.testing.assert_allclose(lens.project(points.reshape(-1, 3)), np.repeat(pixels, 3, axis=0), atol=1e-3)
        depths = (points.reshape(-1, 3) @ lens.R.T + lens.t)[:, 2]
        np.testing.assert_allclose(depths, np.tile([0.3, 1.5, 4.0], 3))


def test_a_camera_turned_away_disagrees_with_the_others_and_only_it():
    cameras = [ring_camera(f"cam_{i}", 2 * np.pi * i / 6) for i in range(6)]
    views = [(camera, sphere_mask(camera)) for camera in cameras]

    def scores(cameras_seen):
        return [mask_agreement(camera, mask, [view for view in views if view[0].name != camera.name], np.zeros(3), 1.4, tolerance=1)
                for camera, mask in zip(cameras_seen, (mask for _, mask in views), strict=True)]

    assert min(scores(cameras)) > 0.99
    # cam_2's calibration turned 10°: its own mask (unchanged) no longer lies on the others' hull.
    cameras[2] = perturbed(cameras[2], 10.0)
    views[2] = (cameras[2], views[2][1])
    turned = scores(cameras)
    assert turned[2] < 0.5 and min(turned[:2] + turned[3:]) > 0.99
    assert mask_agreement(cameras[0], np.zeros((36, 48), dtype=bool), views[1:], np.zeros(3), 1.4) is None


def test_eroded_drops_the_edge_band_and_keeps_the_image_border():
    from mmcsplat.analysis.visual_hull import eroded

    mask = np.zeros((8, 10), bool)
    mask[2:7, 0:6] = True  # touches the image's left border
    inner = eroded(mask, 1)
    expected = np.zeros_like(mask)
    expected[3:6, 0:5] = True  # one pixel off each edge but the image border, which is no edge of the subject
    np.testing.assert_array_equal(inner, expected)
    np.testing.assert_array_equal(eroded(mask, 0), mask)
