"""How well the Gaussians carry landmarks: the confidence of a carried landmark from its anchors' spread,
and the 3D accuracy of carried landmarks against reference positions. The binding itself — which
Gaussians carry each landmark, and how — is :mod:`mmcsplat.scene.landmark_anchors`.

``confidence = exp(−spread / 10 mm)``: 1 where the anchors moved rigidly together, falling as the tracks
tore apart or the landmark sits between parts that moved differently.
"""

from __future__ import annotations

import attrs
import numpy as np

CONFIDENCE_SCALE = 0.010  # metres of anchor spread at which confidence falls to 1/e
MOVED = 0.010  # metres from its fitted-frame position beyond which a landmark has moved (accuracy over moving frames)


def confidence(spread: np.ndarray) -> np.ndarray:
    """exp(−spread / 10 mm): 1 for anchors that agree, falling as they disagree (NaN stays NaN)."""
    return np.exp(-np.asarray(spread) / CONFIDENCE_SCALE)


@attrs.frozen
class LandmarkAccuracy:
    """3D error (mm) of carried landmarks against reference positions at the same frames: median and 90th
    percentile over every (frame after those the landmarks were bound from, landmark) pair with both known,
    and over those where the reference moved more than 1 cm from the bound position; ``still_*`` the same for
    landmarks held at their bound positions (what a method that tracked nothing would score)."""

    median_mm: float | None
    p90_mm: float | None
    moving_median_mm: float | None
    moving_p90_mm: float | None
    still_median_mm: float | None
    still_moving_median_mm: float | None
    pairs: int
    moving_pairs: int
    per_landmark_median_mm: dict[str, float | None]
    per_frame_median_mm: list[float | None]


def percentile_mm(values: np.ndarray, q: float) -> float | None:
    """The ``q``-th percentile of distances ``values`` (metres) in millimetres; None for none."""
    return float(np.percentile(values, q) * 1000) if len(values) else None


def landmark_accuracy(names: tuple[str, ...], carried: np.ndarray, reference: np.ndarray, bound_from: int = 1) -> LandmarkAccuracy:
    """:class:`LandmarkAccuracy` of ``carried`` [T, L, 3] against ``reference`` [T, L, 3] (frame 0 the fitted
    frame, where carried holds the bound positions), scored after the first ``bound_from`` frames: the
    reference there made the binding, so it cannot test it."""
    error = np.linalg.norm(carried - reference, axis=-1)[bound_from:]  # [T - bound_from, L]
    still = np.linalg.norm(carried[:1] - reference, axis=-1)[bound_from:]
    known = np.isfinite(error) & np.isfinite(still)
    moving = known & (still > MOVED)
    per_landmark = {name: percentile_mm(error[known[:, j], j], 50) for j, name in enumerate(names)}
    per_frame = [percentile_mm(error[k][known[k]], 50) for k in range(len(error))]
    return LandmarkAccuracy(
        median_mm=percentile_mm(error[known], 50), p90_mm=percentile_mm(error[known], 90),
        moving_median_mm=percentile_mm(error[moving], 50), moving_p90_mm=percentile_mm(error[moving], 90),
        still_median_mm=percentile_mm(still[known], 50), still_moving_median_mm=percentile_mm(still[moving], 50),
        pairs=int(known.sum()), moving_pairs=int(moving.sum()), per_landmark_median_mm=per_landmark, per_frame_median_mm=[None] * bound_from + per_frame)
