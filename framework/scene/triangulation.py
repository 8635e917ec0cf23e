"""Points from their pixels in several calibrated cameras: the linear (DLT) solution, each row weighted by
its detection's confidence — Pose2Sim's and anipose's triangulation in its simplest form, without their
outlier rejection."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .camera import Camera


def triangulate(cameras: Sequence[Camera], pixels: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """[L, 3] points from ``pixels`` [C, L, 2] in ``cameras`` weighted by ``weights`` [C, L] (0: unused);
    NaN where fewer than two cameras have a weight."""
    projections = np.stack([np.asarray(c.K) @ np.hstack([np.asarray(c.R), np.asarray(c.t)[:, None]]) for c in cameras])  # [C, 3, 4]
    points = np.full((pixels.shape[1], 3), np.nan)
    for j in range(pixels.shape[1]):
        used = np.flatnonzero(weights[:, j] > 0)
        if len(used) < 2:
            continue
        rows = []
        for c in used:
            u, v = pixels[c, j]
            P = projections[c]
            rows += [weights[c, j] * (u * P[2] - P[0]), weights[c, j] * (v * P[2] - P[1])]
        _, _, vt = np.linalg.svd(np.asarray(rows))
        homogeneous = vt[-1]
        points[j] = homogeneous[:3] / homogeneous[3]
    return points
