"""Depth sources of the ``depth-supervised`` initializer."""

from __future__ import annotations

import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import DepthSource
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.session import SessionReader


class SessionDepth(DepthSource):
    """The session's own depth field: ground truth on the synthetic capture, a depth camera's maps where a
    reader stores them. ``noise`` > 0 multiplies each pixel by 1 + ``noise`` · N(0, 1) (seeded by ``seed``
    and the camera's name) to stand in for an estimated map."""

    def __init__(self, noise: float = 0.0, seed: int = 0) -> None:
        if noise < 0:
            raise InputError(f"session depth source: noise must be ≥ 0, got {noise}")
        self.noise = noise
        self.seed = seed

    def depth(self, session: SessionReader, frame: int, camera: Camera) -> np.ndarray:
        data = session.frame(frame, camera.name)
        if data.depth is None:
            raise InputError(f"session depth source: camera {camera.name!r} has no depth map at frame {frame} in {session.url}")
        depth = np.asarray(data.depth, dtype=np.float32)
        if self.noise:
            generator = np.random.default_rng([self.seed, frame, *camera.name.encode()])
            depth = depth * (1 + self.noise * generator.standard_normal(depth.shape)).astype(np.float32)
        return depth
