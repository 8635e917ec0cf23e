"""The synthetic rig: a ring of distorted cameras looking down at the mat, and the rays through their
pixels."""

from __future__ import annotations

import numpy as np

from mmcsplat.scene.camera import Camera, look_at

#: The reference rig (Cotton & Peyton 2023): 2048×1536 sensors with about 1740 px focal length.
REFERENCE_WIDTH = 2048
REFERENCE_FOCAL = 1740.0
RING_RADIUS = 1.2  # metres from the mat centre
RING_HEIGHT = 1.0  # metres above the mat


def camera_names(count: int) -> tuple[str, ...]:
    """The names of a synthetic rig of ``count`` cameras, in ring order."""
    return tuple(f"cam_{i}" for i in range(count))


def ring_cameras(count: int, width: int, height: int, rng: np.random.Generator) -> list[Camera]:
    """``count`` cameras ``cam_0``… evenly around the mat, each varied slightly (position ±3 cm, azimuth
    ±3°, aim ±2 cm, roll ±1°, focal length ±1 %, principal point ±1 % of the width, k1 in −0.12…−0.08,
    k2 in 0.005…0.02), with intrinsics scaled from the reference rig to ``width`` (square pixels)."""
    cameras = []
    focal = REFERENCE_FOCAL * width / REFERENCE_WIDTH
    for i, name in enumerate(camera_names(count)):
        azimuth = 2 * np.pi * i / count + np.radians(rng.uniform(-3, 3))
        radius = RING_RADIUS + rng.uniform(-0.03, 0.03)
        centre = np.array([radius * np.cos(azimuth), radius * np.sin(azimuth), RING_HEIGHT + rng.uniform(-0.03, 0.03)])
        target = np.array([*rng.uniform(-0.02, 0.02, size=2), 0.05])
        R = look_at(centre, target, np.radians(rng.uniform(-1, 1)))
        f = focal * rng.uniform(0.99, 1.01)
        cx, cy = (width - 1) / 2 + rng.uniform(-0.01, 0.01) * width, (height - 1) / 2 + rng.uniform(-0.01, 0.01) * width
        K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]])
        distortion = [rng.uniform(-0.12, -0.08), rng.uniform(0.005, 0.02), 0.0, 0.0, 0.0]
        cameras.append(Camera(name, width, height, K, R, -R @ centre, distortion))
    return cameras


def pixel_rays(camera: Camera, samples: int = 1) -> np.ndarray:
    """World directions [H·W·samples², 3] of rays through ``samples``² points spread evenly over each
    pixel of the distorted image (one at the centre when ``samples`` is 1; pixel (u, v) is centred at
    (u, v), OpenCV's convention), row-major by pixel, then by sub-sample. Each direction has camera-z
    component 1, so a hit at ray parameter s lies at camera depth s."""
    offsets = (np.arange(samples) + 0.5) / samples - 0.5
    v, u, dv, du = np.meshgrid(np.arange(camera.height), np.arange(camera.width), offsets, offsets, indexing="ij")
    # meshgrid orders the axes (v, u, dv, du) as given, so flattening keeps pixels row-major.
    pixels = np.stack([u + du, v + dv], axis=-1).reshape(-1, 2).astype(np.float64)
    normalised = camera.undistort(pixels)
    directions = np.concatenate([normalised, np.ones((len(normalised), 1))], axis=1)
    return directions @ camera.R  # camera → world: R.T @ d, row-wise


def sphere_pixel_boxes(camera: Camera, centres: np.ndarray, radii: np.ndarray, margin: float = 1.0) -> np.ndarray:
    """Pixel ranges [E, 4] (u0, u1, v0, v1; half-open, clipped to the image) holding every pixel whose
    area meets the image of sphere e (world ``centres`` [E, 3], ``radii`` [E]) in the distorted image.

    Exact tangent bounds in the pinhole image, then the box's outline pushed through the distortion
    (densely sampled, plus ``margin`` px); a sphere reaching the edge of the lens model's valid range
    gets the whole image.
    """
    local = centres @ camera.R.T + camera.t
    distance_xz, distance_yz = np.hypot(local[:, 0], local[:, 2]), np.hypot(local[:, 1], local[:, 2])
    bounds = []
    for lateral, distance in ((local[:, 0], distance_xz), (local[:, 1], distance_yz)):
        angle = np.arctan2(lateral, local[:, 2])
        half = np.arcsin(np.clip(radii / np.maximum(distance, 1e-9), 0.0, 1.0))
        bounds.append(np.tan(np.clip(np.stack([angle - half, angle + half], axis=1), -1.2, 1.2)))
    (x0, x1), (y0, y1) = bounds[0].T, bounds[1].T
    # The outline of the unit square, 16 points per side, stretched over each box.
    t = np.linspace(0.0, 1.0, 16)
    side_u, side_v = np.concatenate([t, 0 * t, t, 0 * t + 1]), np.concatenate([0 * t, t, 0 * t + 1, t])
    xs = x0[:, None] + (x1 - x0)[:, None] * side_u
    ys = y0[:, None] + (y1 - y0)[:, None] * side_v
    pixels = camera.distort(np.stack([xs, ys], axis=-1).reshape(-1, 2)).reshape(len(centres), -1, 2)
    low, high = pixels.min(axis=1) - 0.5 - margin, pixels.max(axis=1) + 0.5 + margin
    boxes = np.stack([np.floor(low[:, 0]), np.ceil(high[:, 0]), np.floor(low[:, 1]), np.ceil(high[:, 1])], axis=1)
    boxes = np.clip(boxes, 0, [camera.width, camera.width, camera.height, camera.height]).astype(int)
    # Behind the camera, or wider than the lens model's monotonic range: take the whole image.
    unsafe = (local[:, 2] <= radii) | (np.maximum(np.abs(bounds[0]), np.abs(bounds[1])).max(axis=1) >= 1.2)
    boxes[unsafe] = [0, camera.width, 0, camera.height]
    return boxes
