"""Analyses on the visual hull of subject masks (:mod:`mmcsplat.scene.visual_hull`): the held-out evaluation
measures floaters — the share of opacity mass whose Gaussians lie outside the hull of the session's masks
— and each camera's agreement with the others — the share of its mask whose rays meet the hull of the
other cameras' masks (a camera with wrong extrinsics sees the subject where the others do not).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mmcsplat.scene.camera import Camera
from mmcsplat.scene.visual_hull import View, in_hull, mask_votes, pixel_rays

#: Masks are dilated by this many pixels before the floater test (their own edge errors are no floaters).
FLOATER_MARGIN_PX = 2
#: :func:`mask_agreement` tests this many depths along each pixel's ray …
RAY_SAMPLES = 64
#: … of at most this many of the mask's pixels (evenly spread over it): on the synthetic capture at
#: 256 × 192 its scores are within 0.03 of 128 depths × 2000 pixels, in a tenth of the time.
AGREEMENT_PIXELS = 500

def dilated(mask: np.ndarray, margin_px: int) -> np.ndarray:
    """``mask`` grown by ``margin_px`` pixels (a disc)."""
    if margin_px <= 0:
        return mask
    import cv2

    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1, 2 * margin_px + 1))
    return cv2.dilate(mask.astype(np.uint8), kernel) > 0


def eroded(mask: np.ndarray, margin_px: int) -> np.ndarray:
    """``mask`` without the pixels within ``margin_px`` pixels of its edge (a square: 8-neighbours)."""
    if margin_px <= 0:
        return mask
    import cv2

    kernel = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
    return cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=1) > 0


def floater_share(means: np.ndarray, opacities: np.ndarray, views: Sequence[View], tolerance: int = 0) -> float:
    """The share of opacity mass (sum of opacities, in [0, 1] each) of Gaussians whose centres ``means``
    [N, 3] lie outside the visual hull of ``views`` (masks already dilated); 0 for no opacity at all."""
    total = float(np.sum(opacities))
    if total <= 0:
        return 0.0
    outside = ~in_hull(*mask_votes(np.asarray(means, dtype=np.float64), views), tolerance)
    return float(np.sum(opacities[outside]) / total)


def mask_agreement(camera: Camera, mask: np.ndarray, others: Sequence[View], center: np.ndarray, radius: float,
                   samples: int = RAY_SAMPLES, max_pixels: int = AGREEMENT_PIXELS, tolerance: int = 0) -> float | None:
    """The share of ``camera``'s ``mask`` [H, W] bool pixels whose ray, sampled at ``samples`` depths
    through the sphere of ``radius`` about ``center``, meets the visual hull of the ``others`` views
    (masks already dilated; ``tolerance`` as for :func:`in_hull`); ``None`` for an empty mask. The hull
    of the others contains the subject, so a camera consistent with them scores about 1; one whose
    calibration (or mask) is off sees the subject where the others see none, and scores less."""
    ys, xs = np.nonzero(mask)
    if not len(xs):
        return None
    pick = np.unique(np.linspace(0, len(xs) - 1, min(len(xs), max_pixels)).round().astype(int))
    distance = float(np.linalg.norm(camera.center - np.asarray(center, dtype=np.float64)))
    depths = np.linspace(max(distance - radius, 1e-3 * distance), distance + radius, samples)
    points = pixel_rays(camera, np.stack([xs[pick], ys[pick]], axis=1), depths).reshape(-1, 3)
    met = in_hull(*mask_votes(points, others), tolerance).reshape(len(pick), samples).any(axis=1)
    return float(met.mean())
