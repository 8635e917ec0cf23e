"""Depth sources of the ``depth-supervised`` initializer."""

from __future__ import annotations

import attrs
import numpy as np

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import DepthSource
from mmcsplat.plugin_api.parameters import at_least, parameter
from mmcsplat.scene.camera import Camera
from mmcsplat.storage.session import SessionReader


@attrs.frozen
class SessionDepth(DepthSource):
    """The session's own depth field: ground truth on the synthetic capture, a depth camera's maps where a
    reader stores them; optionally with multiplicative noise to stand in for an estimated map."""

    noise: float = parameter(0.0, doc="each pixel times 1 + noise · N(0, 1)", validator=at_least(0))
    seed: int = parameter(0, doc="seed of the noise (with the camera's name)")

    def depth(self, session: SessionReader, frame: int, camera: Camera) -> np.ndarray:
        data = session.frame(frame, camera.name)
        if data.depth is None:
            raise InputError(f"session depth source: camera {camera.name!r} has no depth map at frame {frame} in {session.url}")
        depth = np.asarray(data.depth, dtype=np.float32)
        if self.noise:
            generator = np.random.default_rng([self.seed, frame, *camera.name.encode()])
            depth = depth * (1 + self.noise * generator.standard_normal(depth.shape)).astype(np.float32)
        return depth
