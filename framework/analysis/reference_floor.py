"""How close a tracker of one body could come to a 3D reference that is not itself one body.

A triangulated reference (Pose2Sim's TRC, a keypoint detector's joints) changes its bones' lengths from frame
to frame; carried landmarks ride on one body whose bones keep theirs. So each reference frame is moved to the
nearest set of landmarks with the bind frames' bone lengths (:func:`~mmcsplat.scene.human_skeleton.fixed_bones`):
a tracker that placed that body perfectly at every frame, and landmarks bound as the carried ones are, would
score that far from the reference. It is the floor under the 3D and 2D accuracy of ``mmcsplat landmarks``, and
how far the tracks are from that body is their error with the reference's inconsistency taken out.

The nearest body is a least-squares problem per frame: the landmarks' squared displacement plus the bones'
squared length errors weighted by :data:`BONE_WEIGHT` (metres), solved by Levenberg–Marquardt steps batched
over frames with NumPy: the Pose2Sim demo's 100 frames in 0.2 s, 5 000 frames in 9 s on 2 cores. scipy's
``least_squares`` solves the same problem one frame at a time, 20 times slower; the tests hold the two to each other.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from mmcsplat.analysis.landmark_binding import percentile_mm
from mmcsplat.scene.human_skeleton import fixed_bones

#: How much a bone's length error (m) weighs against a landmark's displacement (m): 1 mm of bone costs as
#: much as 10 cm of displacement, so the lengths hold to about 10 µm on the Pose2Sim demo.
BONE_WEIGHT = 100.0
STEPS = 500  # at most; the Pose2Sim demo's frames converge in 60–200
CHUNK = 256  # frames solved at once: a [CHUNK, 3L, 3L] system


def nearest_body(reference: np.ndarray, bones: np.ndarray, lengths: np.ndarray, steps: int = STEPS) -> np.ndarray:
    """[T, L, 3]: each frame of ``reference`` [T, L, 3] moved to the nearest landmarks whose ``bones`` [B, 2]
    (index pairs) have the ``lengths`` [B] (NaN: the bone is not held). NaN where the reference is unknown; a
    bone with an unknown end is not held that frame."""
    result = np.full(reference.shape, np.nan)
    for start in range(0, len(reference), CHUNK):
        result[start:start + CHUNK] = _solve(reference[start:start + CHUNK], bones, lengths, steps)
    return result


def _solve(reference: np.ndarray, bones: np.ndarray, lengths: np.ndarray, steps: int) -> np.ndarray:
    """:func:`nearest_body` for one chunk of frames: damped Newton steps from the reference itself, each frame
    accepting a step only where it lowers that frame's cost."""
    known = np.all(np.isfinite(reference), axis=-1)  # [T, L]
    target = np.where(known[..., None], reference, 0.0)
    held = known[:, bones[:, 0]] & known[:, bones[:, 1]] & np.isfinite(lengths)  # [T, B]
    rest = np.where(np.isfinite(lengths), lengths, 0.0)
    points = target.copy()
    damping = np.full(len(points), 1e-3)  # Levenberg–Marquardt's, per frame: a full Newton step can fold a bone through zero length
    cost = _cost(points, target, bones, rest, held)
    active = np.ones(len(points), dtype=bool)
    for _ in range(steps):
        index = np.flatnonzero(active)
        if not index.size:
            break
        step = _newton_step(points[index], target[index], bones, rest, held[index], damping[index])
        trial = points[index] - step
        trial_cost = _cost(trial, target[index], bones, rest, held[index])
        better = trial_cost < cost[index]
        points[index[better]], cost[index[better]] = trial[better], trial_cost[better]
        damping[index] = np.where(better, damping[index] / 3, damping[index] * 4)
        # A frame is done when its accepted step is under a micrometre, or no step, however damped, lowers its cost.
        moved = np.abs(step).max(axis=(1, 2))
        active[index[(better & (moved < 1e-6)) | (damping[index] > 1e12)]] = False
    return np.where(known[..., None], points, np.nan)


def _cost(points: np.ndarray, target: np.ndarray, bones: np.ndarray, rest: np.ndarray, held: np.ndarray) -> np.ndarray:
    """[T]: each frame's squared displacement plus its weighted squared bone-length errors."""
    length = np.linalg.norm(points[:, bones[:, 0]] - points[:, bones[:, 1]], axis=-1)
    return ((points - target) ** 2).sum(axis=(1, 2)) + BONE_WEIGHT**2 * (np.where(held, length - rest, 0.0) ** 2).sum(axis=1)


def _newton_step(points: np.ndarray, target: np.ndarray, bones: np.ndarray, rest: np.ndarray, held: np.ndarray,
                 damping: np.ndarray) -> np.ndarray:
    """[T, L, 3]: the damped Newton step of :func:`_cost` (subtract it)."""
    count, joints = points.shape[:2]
    offset = points[:, bones[:, 0]] - points[:, bones[:, 1]]  # [T, B, 3]
    length = np.linalg.norm(offset, axis=-1)
    direction = offset / np.maximum(length, 1e-12)[..., None]
    weight = BONE_WEIGHT**2
    # The Hessian: identity for the displacements (an unknown landmark is held where it is), and per held bone
    # w²·(e_a − e_b)(e_a − e_b)ᵀ ⊗ (u·uᵀ + curvature); the damping adds to the diagonal in its proportion.
    normal = np.zeros((count, joints, 3, joints, 3))
    stretch = np.where(held, length - rest, 0.0)
    across = np.eye(3) - direction[..., :, None] * direction[..., None, :]
    # The length's own curvature, stretch/length·(I − u·uᵀ), matters with a weight this large: without it the
    # steps crawl where a bone is far from its length.
    outer = weight * held[..., None, None] * (direction[..., :, None] * direction[..., None, :]
                                               + (stretch / np.maximum(length, 1e-12))[..., None, None] * across)  # [T, B, 3, 3]
    gradient = points - target
    pull = (weight * stretch)[..., None] * direction  # [T, B, 3]
    for b, (first, second) in enumerate(bones):
        normal[:, first, :, first] += outer[:, b]
        normal[:, second, :, second] += outer[:, b]
        normal[:, first, :, second] -= outer[:, b]
        normal[:, second, :, first] -= outer[:, b]
        gradient[:, first] += pull[:, b]
        gradient[:, second] -= pull[:, b]
    normal = normal.reshape(count, 3 * joints, 3 * joints)
    diagonal = np.einsum("tii->ti", normal)
    normal[:, np.arange(3 * joints), np.arange(3 * joints)] = 1 + diagonal + damping[:, None] * (1 + np.abs(1 + diagonal))
    return np.linalg.solve(normal, gradient.reshape(count, 3 * joints, 1)).reshape(points.shape)


def reference_floor(names: Sequence[str], carried: np.ndarray, reference: np.ndarray, bound_from: int) -> tuple[dict[str, Any], np.ndarray] | None:
    """The reference's floor (module docstring) for ``carried`` and ``reference`` [T, L, 3] landmarks named
    ``names``, bound from the first ``bound_from`` frames and scored after them, as
    :func:`~mmcsplat.analysis.landmark_binding.landmark_accuracy` scores: a record for landmarks.json and the
    nearest body [T, L, 3]; None where the names hold no fixed bone known at the bind frames, or no frame
    is left to score."""
    pairs = fixed_bones(list(names))
    if not pairs or len(reference) <= bound_from:
        return None
    bones = np.array([[names.index(a), names.index(b)] for a, b in pairs])
    with np.errstate(all="ignore"):
        lengths = np.nanmedian(np.linalg.norm(reference[:bound_from, bones[:, 0]] - reference[:bound_from, bones[:, 1]], axis=-1), axis=0)
    if not np.isfinite(lengths).any():
        return None
    body = nearest_body(reference, bones, lengths)
    floor = np.linalg.norm(body - reference, axis=-1)[bound_from:]
    tracks = np.linalg.norm(carried - body, axis=-1)[bound_from:]
    known = np.isfinite(floor) & np.isfinite(tracks)
    if not known.any():
        return None
    record = {
        "bones": [f"{a}-{b}" for (a, b), length in zip(pairs, lengths, strict=True) if np.isfinite(length)],
        "lengths_from_frames": int(bound_from),
        "median_mm": percentile_mm(floor[known], 50), "p90_mm": percentile_mm(floor[known], 90),
        "per_landmark_median_mm": {name: percentile_mm(floor[known[:, j], j], 50) for j, name in enumerate(names)},
        "carried_median_mm": percentile_mm(tracks[known], 50), "carried_p90_mm": percentile_mm(tracks[known], 90),
    }
    return record, body
