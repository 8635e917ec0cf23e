"""Reading a synthetic capture's ground truth: the 3D surface points and joints at any frame, the masks and
depth maps, and which surface points a camera sees — what a tracking evaluation compares against."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mmcsplat.scene.camera import Camera
from mmcsplat.storage.ground_truth import Frames, GroundTruthReader
from mmcsplat.synthetic.writer import CALIBRATION


class SynthGroundTruth(GroundTruthReader):
    """The ground truth of a capture written by :func:`~.synthesize.synthesize`, opened from the capture
    folder or its ``ground_truth.zarr`` (:class:`~mmcsplat.storage.ground_truth.GroundTruthReader`), with
    the capture's cameras and what each sees.

    ``surface_points(frames)`` [..., P, 3] and ``joints(frames)`` [..., J, 3] are world positions in
    metres; ``frames`` is a frame index (→ [P, 3]), a slice or a sequence of indices (→ [T', P, 3]).
    """

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self.fps = float(self.attribute("fps"))
        self.num_frames = int(self.attribute("num_frames"))
        self.seed = int(self.attribute("seed"))
        self.surface_point_parts = self.names("surface_points")
        self.joint_names = self.names("joints")

    def cameras(self) -> list[Camera]:
        """The capture's calibrated (distorted) cameras, from the calibration.toml beside it."""
        from mmcsplat.storage.calibration import read_calibration

        return read_calibration(self.path.parent / CALIBRATION)

    def surface_points(self, frames: Frames = slice(None)) -> np.ndarray:
        """World positions of the labelled surface points at ``frames``."""
        return self.points("surface_points", frames)

    def joints(self, frames: Frames = slice(None)) -> np.ndarray:
        """World positions of the joint centres at ``frames``."""
        return self.points("joints", frames)

    def mask(self, camera: str, t: int) -> np.ndarray:
        """[H, W] bool: the infant in ``camera``'s (distorted) frame ``t``."""
        return np.asarray(self._field("masks", camera)[self._check(t)]) > 0

    def depth(self, camera: str, t: int) -> np.ndarray:
        """[H, W] float32: camera-z depth in metres of the nearest surface at each pixel, 0 where none."""
        return np.asarray(self._field("depth", camera)[self._check(t)], dtype=np.float32)

    def visible_points(self, camera: Camera, t: int, tolerance: float = 0.01) -> np.ndarray:
        """[P] bool: surface points at frame ``t`` that ``camera`` sees — inside the image and not more than
        ``tolerance`` metres behind the depth map at their (nearest) pixel."""
        points = self.surface_points(t)
        depth = (points @ camera.R.T + camera.t)[:, 2]
        pixels = np.round(camera.project(points)).astype(int)
        inside = (depth > 0) & np.all((pixels >= 0) & (pixels < [camera.width, camera.height]), axis=1)
        u, v = np.clip(pixels[:, 0], 0, camera.width - 1), np.clip(pixels[:, 1], 0, camera.height - 1)
        surface = self.depth(camera.name, t)[v, u]
        return inside & ((surface == 0) | (depth <= surface + tolerance))

    def _check(self, t: int) -> int:
        if not 0 <= t < self.num_frames:
            raise IndexError(f"{self.path}: frame {t} out of range (the capture has {self.num_frames})")
        return t

    def _field(self, field: str, camera: str):
        try:
            return self.group[field][camera]
        except KeyError:
            raise KeyError(f"{self.path}: no {field} for camera {camera!r}") from None
