"""A tiny self-consistent capture for trainer tests: known Gaussians rendered by torch-reference into a
ring of cameras and written to a session store (masks from alpha, depth from the renderer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from mmcsplat.camera import Camera
from mmcsplat.rendering import Gaussians, RenderCameras
from mmcsplat.store import SessionWriter

WIDTH, HEIGHT, FOCAL = 48, 36, 40.0


def ring_camera(name: str, angle: float, radius: float = 1.2, height: float = 0.8) -> Camera:
    center = np.array([radius * np.cos(angle), radius * np.sin(angle), height])
    forward = -center / np.linalg.norm(center)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    K = [[FOCAL, 0, WIDTH / 2 - 0.5], [0, FOCAL, HEIGHT / 2 - 0.5], [0, 0, 1]]
    return Camera(name, WIDTH, HEIGHT, K, R, -R @ center)


def subject(count: int = 150, seed: int = 0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(count, 3, generator=g, dtype=torch.float64) * torch.tensor([0.12, 0.06, 0.04], dtype=torch.float64)
    quats = torch.randn(count, 4, generator=g, dtype=torch.float64)
    log_scales = torch.full((count, 3), float(np.log(0.03)), dtype=torch.float64)
    opacity_logits = torch.full((count,), 2.0, dtype=torch.float64)
    colors = torch.rand(count, 3, generator=g, dtype=torch.float64)
    return Gaussians(means, quats, log_scales, opacity_logits, colors, torch.ones(count, 1, dtype=torch.float64))


def write_session(path: Path, cameras: int = 5, heldout: tuple[str, ...] = ("cam_0",), blank: tuple[str, ...] = ()) -> Path:
    """Render ``subject()`` into ``cameras`` ring cameras; cameras in ``blank`` get an empty image/mask."""
    from mmcsplat.backends.torch_reference import rasterize

    rig = [ring_camera(f"cam_{i}", 2 * np.pi * i / cameras) for i in range(cameras)]
    gaussians = subject()
    with SessionWriter(path, cameras=rig, num_frames=1, fps=30.0, heldout=heldout, source="fitting-scene") as writer:
        for camera in rig:
            out = rasterize(gaussians, RenderCameras.from_cameras([camera], dtype=torch.float64))
            rgb = (out.rgb[0].clamp(0, 1).numpy() * 255).round().astype(np.uint8)
            mask = out.alpha[0].numpy() > 0.5
            if camera.name in blank:
                rgb[:] = 0
                mask[:] = False
            writer.write_frame(camera.name, 0, rgb, mask=mask, depth=out.depth[0].numpy().astype(np.float32))
    return path


CONFIG = """
[fit]
iterations = {iterations}
checkpoint_every = {checkpoint_every}
lambda_seg = 3.0

[renderer]
name = "torch-reference"

[[initializer]]
name = "random"
num_points = 200
half_size = 0.25

[[initializer]]
name = "masked"
radius = 2.0
every = 10

[densifier]
name = "default"
start = 10
stop = 35
every = 10
"""


def write_config(path: Path, iterations: int = 60, checkpoint_every: int = 20) -> Path:
    path.write_text(CONFIG.format(iterations=iterations, checkpoint_every=checkpoint_every))
    return path
