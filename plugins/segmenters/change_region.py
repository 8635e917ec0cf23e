"""Where the subject can be: the convex hull of the visual hull of change over a whole sequence.

A subject that barely moves still moves somewhere — a hand, a foot, the head — and static equipment (a
treadmill, a mat's fold, a chair) never does. Each camera's *changed* pixels are those whose colour
differs from its sequence's per-pixel median; the voxels that the cameras seeing them agree changed at
some time are where the subject moved; the convex hull of their main connected pieces, grown by a margin,
holds the still parts between the moving ones (an infant's trunk between its limbs, an adult's torso
between arms and legs). Its projection into each camera is the region a mask may cover.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from scipy import ndimage

from mmcsplat.plugins.segmenters.postprocess import open_close
from mmcsplat.scene.camera import Camera
from mmcsplat.scene.visual_hull import mask_hits

#: Directions the hull's points are pushed out along by the margin: the axes and the cube's diagonals.
_OUTWARD = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)], float)


def changed(image: np.ndarray, median: np.ndarray, threshold: float) -> np.ndarray:
    """[H, W] bool: the pixels of ``image`` whose largest per-channel difference to ``median`` exceeds
    ``threshold`` grey levels, single-pixel specks (sensor noise, compression) opened away."""
    difference = np.abs(image.astype(np.int16) - median.astype(np.int16)).max(axis=-1)
    return open_close(difference > threshold, 1, 0)


def moving_voxels(grid: np.ndarray, cameras: Sequence[Camera], ever_changed: Sequence[np.ndarray], agreement: float) -> np.ndarray:
    """[N] bool over ``grid`` [N, 3]: seen by at least 2 cameras, and on the ``ever_changed`` pixels of at
    least ``agreement`` of those that see it."""
    seen = np.zeros(len(grid), int)
    inside = np.zeros(len(grid), int)
    for _, sees, on_mask in mask_hits(grid, list(zip(cameras, ever_changed, strict=True))):
        seen += sees
        inside += on_mask
    return (seen >= 2) & (inside >= agreement * seen)


#: Share of the largest connected piece of changed voxels a piece must reach to be kept: a leg and an arm
#: that moved are separate pieces, a speck of noise is not one.
MAIN_PIECE_SHARE = 0.1


def main_pieces(points: np.ndarray, basis: np.ndarray, size: float) -> np.ndarray:
    """[N] bool: the points of the 26-connected pieces of ``points`` [N, 3] — voxel centres of a grid with
    axes ``basis`` [3, 3] (rows) and spacing ``size`` — of at least :data:`MAIN_PIECE_SHARE` of the
    largest one's voxels."""
    cells = np.round(points @ basis.T / size).astype(int)
    cells -= cells.min(axis=0)
    occupied = np.zeros(cells.max(axis=0) + 1, bool)
    occupied[tuple(cells.T)] = True
    labels, count = ndimage.label(occupied, structure=np.ones((3, 3, 3)))
    if count <= 1:
        return np.ones(len(points), bool)
    piece = labels[tuple(cells.T)]
    sizes = np.bincount(piece)
    return sizes[piece] >= MAIN_PIECE_SHARE * sizes[1:].max()


def hull_masks(points: np.ndarray, cameras: Sequence[Camera], margin: float) -> list[np.ndarray]:
    """Per camera, [H, W] bool: the projection of the convex hull of ``points`` [N, 3] grown by ``margin``
    metres (the hull of the points pushed out along the axes and diagonals)."""
    grown = (points[:, None, :] + margin * _OUTWARD[None] / np.linalg.norm(_OUTWARD, axis=1)[None, :, None]).reshape(-1, 3)
    grown = np.concatenate([points, grown])
    masks = []
    for camera in cameras:
        in_front = (grown @ camera.R.T + camera.t)[:, 2] > 0
        pixels = camera.project(grown[in_front]).astype(np.float32)
        mask = np.zeros((camera.height, camera.width), np.uint8)
        if len(pixels):
            polygon = cv2.convexHull(np.clip(pixels, -1e6, 1e6)).round().astype(np.int32)
            cv2.fillConvexPoly(mask, polygon, 1)
        masks.append(mask.astype(bool))
    return masks
