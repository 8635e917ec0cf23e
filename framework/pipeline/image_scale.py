"""The scale a capture's images are stored at: a number, or ``auto`` — sized for a CPU whatever the cameras'
resolution."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from mmcsplat.plugin_api.errors import InputError

if TYPE_CHECKING:
    from mmcsplat.scene.camera import Camera

#: ``scale = "auto"``: the stored images' longer side at most this many pixels — 270 × 480 for 1080 × 1920
#: video, where a 2-core CPU fits and tracks a capture in minutes (docs/performance.md) — and never enlarged.
AUTO_SCALE = "auto"
AUTO_LONGEST_SIDE = 480


def checked_scale(scale: float | str) -> float | str:
    """``scale`` when it is a number in (0, 1] or :data:`AUTO_SCALE`, else an error: the stored images are the
    recorded ones or smaller (an upscaled image adds pixels and no detail; 50 meant as per cent would ask for
    2 500 times the memory)."""
    if scale != AUTO_SCALE and (isinstance(scale, str) or not 0 < scale <= 1):
        raise InputError(f"scale must be a number in (0, 1], the share of the recorded size (0.5: half), or {AUTO_SCALE!r}; got {scale!r}")
    return scale


def resolve_scale(scale: float | str, cameras: Sequence[Camera]) -> float:
    """``scale`` as a number: itself, or for :data:`AUTO_SCALE` the largest ≤ 1 that brings every camera's
    longer side to at most :data:`AUTO_LONGEST_SIDE` pixels."""
    if checked_scale(scale) == AUTO_SCALE:
        return min(1.0, AUTO_LONGEST_SIDE / max(max(camera.width, camera.height) for camera in cameras))
    return float(scale)
