"""Landmarks carried by the Gaussians: bound once at the fitted frame, then moved with them.

Each landmark is attached to its ``k`` nearest subject Gaussians within ``max_distance`` at the fitted
frame, with weights falling with distance (1 / (d + 5 mm)), and anchored in each Gaussian's local frame:
offset ``o = R₀ᵀ (p − μ₀)``. At frame t each anchor proposes ``μ_t + R_t o`` — so a Gaussian's rotation
carries a landmark that lies off its centre, as a bone carries a joint centre inside the limb — and the
landmark is their weighted mean. The weighted spread of the proposals around it (``spread``, metres) says
how much the anchors disagree: small when they moved rigidly together, large when the tracks tore apart
or the landmark sits between parts that moved differently. ``confidence = exp(−spread / 10 mm)``.

A landmark with no subject Gaussian within ``max_distance`` (or unknown at the fitted frame) is left
unbound and reported: its trajectory is NaN, never invented.
"""

from __future__ import annotations

import attrs
import numpy as np
import torch
from scipy.spatial import cKDTree

from mmcsplat.scene.quaternions import quat_to_rotmat

ANCHORS = 8
MAX_DISTANCE = 0.1  # metres: a joint centre lies a few centimetres inside an infant's limb, more in an adult's
WEIGHT_SOFTENING = 0.005  # metres added to each distance, so that a Gaussian at the landmark does not take all the weight
CONFIDENCE_SCALE = 0.010  # metres of anchor spread at which confidence falls to 1/e
MOVED = 0.010  # metres from its fitted-frame position beyond which a landmark has moved (accuracy over moving frames)


def rotations(quats: np.ndarray | torch.Tensor) -> np.ndarray:
    """[N, 3, 3] rotation matrices of [N, 4] (w, x, y, z) quaternions (normalised)."""
    return quat_to_rotmat(torch.as_tensor(np.asarray(quats), dtype=torch.float64)).numpy()


@attrs.frozen(eq=False)
class LandmarkBinding:
    """Which Gaussians carry each landmark: ``anchors[j]`` indices [k], ``weights[j]`` [k] summing to 1,
    ``offsets[j]`` [k, 3] in the anchors' local frames; ``bound[j]`` False for a landmark left unbound
    (its anchors, weights and offsets are then zeros)."""

    names: tuple[str, ...]
    anchors: np.ndarray
    weights: np.ndarray
    offsets: np.ndarray
    bound: np.ndarray
    distances: np.ndarray  # [L] metres to the nearest candidate Gaussian (inf when none)

    @property
    def unbound(self) -> list[str]:
        return [name for name, ok in zip(self.names, self.bound, strict=True) if not ok]


def bind_landmarks(names: tuple[str, ...], positions: np.ndarray, means: np.ndarray, quats: np.ndarray, candidates: np.ndarray,
                   anchors: int = ANCHORS, max_distance: float = MAX_DISTANCE) -> LandmarkBinding:
    """Bind landmarks at ``positions`` [L, 3] to the Gaussians ``candidates`` (indices into ``means`` [N, 3]
    and ``quats`` [N, 4] at the fitted frame): the ``anchors`` nearest within ``max_distance``."""
    count = len(names)
    k = max(1, min(anchors, len(candidates)))
    result = {"anchors": np.zeros((count, k), dtype=np.int64), "weights": np.zeros((count, k)), "offsets": np.zeros((count, k, 3))}
    bound = np.zeros(count, dtype=bool)
    nearest = np.full(count, np.inf)
    if len(candidates):
        tree = cKDTree(means[candidates])
        valid = np.all(np.isfinite(positions), axis=1)
        distance, local = tree.query(np.where(valid[:, None], positions, 0.0), k=k)
        distance, local = distance.reshape(count, k), local.reshape(count, k)
        R = rotations(quats[candidates])
        for j in np.flatnonzero(valid):
            nearest[j] = distance[j, 0]
            close = distance[j] <= max_distance
            if not close.any():
                continue
            chosen = local[j, close]
            weights = 1.0 / (distance[j, close] + WEIGHT_SOFTENING)
            result["anchors"][j, : len(chosen)] = candidates[chosen]
            result["weights"][j, : len(chosen)] = weights / weights.sum()
            result["offsets"][j, : len(chosen)] = np.einsum("kji,kj->ki", R[chosen], positions[j] - means[candidates[chosen]])
            bound[j] = True
    return LandmarkBinding(tuple(names), bound=bound, distances=nearest, **result)


def carry(binding: LandmarkBinding, means: np.ndarray, quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions [L, 3], spread [L] metres) of the bound landmarks given the Gaussians' ``means`` [N, 3]
    and ``quats`` [N, 4] at one frame; NaN for unbound landmarks."""
    anchors = binding.anchors
    R = rotations(quats[anchors.ravel()]).reshape(*anchors.shape, 3, 3)
    proposals = means[anchors] + np.einsum("lkij,lkj->lki", R, binding.offsets)  # [L, k, 3]
    positions = np.einsum("lk,lki->li", binding.weights, proposals)
    spread = np.sqrt(np.einsum("lk,lk->l", binding.weights, np.sum((proposals - positions[:, None]) ** 2, axis=-1)))
    positions[~binding.bound] = np.nan
    spread[~binding.bound] = np.nan
    return positions, spread


def confidence(spread: np.ndarray) -> np.ndarray:
    """exp(−spread / 10 mm): 1 for anchors that agree, falling as they disagree (NaN stays NaN)."""
    return np.exp(-np.asarray(spread) / CONFIDENCE_SCALE)


@attrs.frozen
class LandmarkAccuracy:
    """3D error (mm) of carried landmarks against reference positions at the same frames: median and 90th
    percentile over every (frame after the first, landmark) pair with both known, and over those where the
    reference moved more than 1 cm from its fitted-frame position; ``still_*`` the same for landmarks held
    at their fitted-frame positions (what a method that tracked nothing would score)."""

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


def _stat(values: np.ndarray, q: float) -> float | None:
    return float(np.percentile(values, q) * 1000) if len(values) else None


def landmark_accuracy(names: tuple[str, ...], carried: np.ndarray, reference: np.ndarray) -> LandmarkAccuracy:
    """:class:`LandmarkAccuracy` of ``carried`` [T, L, 3] against ``reference`` [T, L, 3] (frame 0 the fitted
    frame, where carried equals the binding positions)."""
    error = np.linalg.norm(carried - reference, axis=-1)[1:]  # [T-1, L]
    still = np.linalg.norm(reference[:1] - reference, axis=-1)[1:]
    known = np.isfinite(error) & np.isfinite(still)
    moving = known & (still > MOVED)
    per_landmark = {name: _stat(error[known[:, j], j], 50) for j, name in enumerate(names)}
    per_frame = [_stat(error[k][known[k]], 50) for k in range(len(error))]
    return LandmarkAccuracy(
        median_mm=_stat(error[known], 50), p90_mm=_stat(error[known], 90),
        moving_median_mm=_stat(error[moving], 50), moving_p90_mm=_stat(error[moving], 90),
        still_median_mm=_stat(still[known], 50), still_moving_median_mm=_stat(still[moving], 50),
        pairs=int(known.sum()), moving_pairs=int(moving.sum()), per_landmark_median_mm=per_landmark, per_frame_median_mm=[None, *per_frame])
