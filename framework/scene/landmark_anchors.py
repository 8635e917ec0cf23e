"""Landmarks carried by the Gaussians: bound once at the fitted frame, then moved with them.

Where the reference knows the landmarks over several frames, the binding takes the first ``BIND_FRAMES`` of
them (:func:`bind_over_frames`): one frame of a triangulated reference can be centimetres off (at frame 0 of
the Pose2Sim demo its left ankle is 51 mm from the all-camera triangulation of the same detections, 5 mm at
the next frame), and a landmark bound there would carry that offset through every later frame.

Each landmark is attached to its ``k`` nearest subject Gaussians within ``max_distance`` at the fitted
frame, with weights falling with distance (1 / (d + 5 mm)), and anchored in each Gaussian's local frame:
offset ``o = R₀ᵀ (p − μ₀)``. At frame t each anchor proposes ``μ_t + R_t o`` — so a Gaussian's rotation
carries a landmark that lies off its centre, as a bone carries a joint centre inside the limb — and the
landmark is their weighted mean. The weighted spread of the proposals around it (``spread``, metres) says
how much the anchors disagree: small when they moved rigidly together, large when the tracks tore apart
or the landmark sits between parts that moved differently.

A landmark with no subject Gaussian within ``max_distance`` (or unknown at the fitted frame) is left
unbound and reported: its trajectory is NaN, never invented.

The landmarks' analysis (:mod:`mmcsplat.analysis.landmark_binding`) carries them through a run's tracks;
keypoint guidance (:mod:`mmcsplat.training.keypoint_guidance`) pulls them, differentiably, while tracking.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence

import attrs
import numpy as np
import torch
from scipy.spatial import cKDTree

from .quaternions import quat_to_rotmat

ANCHORS = 8
#: Frames of the reference a landmark is bound from, the fitted one first (docs/landmarks.md, "Binding and carrying").
BIND_FRAMES = 7
MAX_DISTANCE = 0.1  # metres: a joint centre lies a few centimetres inside an infant's limb, more in an adult's
WEIGHT_SOFTENING = 0.005  # metres added to each distance, so that a Gaussian at the landmark does not take all the weight
SUBJECT_OPACITY = 0.1  # Gaussians fainter than this carry no landmark: they are too easily floaters


def rotations(quats: np.ndarray | torch.Tensor) -> np.ndarray:
    """[N, 3, 3] rotation matrices of [N, 4] (w, x, y, z) quaternions (normalised)."""
    return quat_to_rotmat(torch.as_tensor(np.asarray(quats), dtype=torch.float64)).numpy()


def subject_gaussians(params: Mapping[str, torch.Tensor], foreground: np.ndarray) -> np.ndarray:
    """Indices of the Gaussians that may carry landmarks: the subject's (``foreground`` indices; every
    Gaussian when none is) that are not nearly transparent."""
    opaque = torch.sigmoid(params["opacity_logits"].detach()).numpy() >= SUBJECT_OPACITY
    candidates = foreground if len(foreground) else np.arange(len(opaque))
    return candidates[opaque[candidates]]


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


def proposals(binding: LandmarkBinding, means: torch.Tensor, quats: torch.Tensor) -> torch.Tensor:
    """[L, k, 3] each anchor's proposal ``μ + R o`` for its landmark, given the Gaussians' ``means`` [N, 3]
    and ``quats`` [N, 4] at one frame; differentiable with respect to both, in their dtype."""
    anchors = torch.as_tensor(binding.anchors)
    R = quat_to_rotmat(quats[anchors.reshape(-1)]).reshape(*anchors.shape, 3, 3)
    offsets = torch.as_tensor(binding.offsets, dtype=means.dtype)
    return means[anchors] + torch.einsum("lkij,lkj->lki", R, offsets)


def carry(binding: LandmarkBinding, means: np.ndarray, quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions [L, 3], spread [L] metres) of the bound landmarks given the Gaussians' ``means`` [N, 3]
    and ``quats`` [N, 4] at one frame; NaN for unbound landmarks."""
    proposed = proposals(binding, torch.as_tensor(np.asarray(means), dtype=torch.float64),
                         torch.as_tensor(np.asarray(quats), dtype=torch.float64)).numpy()  # [L, k, 3]
    positions = np.einsum("lk,lki->li", binding.weights, proposed)
    spread = np.sqrt(np.einsum("lk,lk->l", binding.weights, np.sum((proposed - positions[:, None]) ** 2, axis=-1)))
    positions[~binding.bound] = np.nan
    spread[~binding.bound] = np.nan
    return positions, spread


def bind_over_frames(names: tuple[str, ...], positions: np.ndarray, states: Sequence[tuple[np.ndarray, np.ndarray]], candidates: np.ndarray,
                     anchors: int = ANCHORS, max_distance: float = MAX_DISTANCE) -> LandmarkBinding:
    """Bind landmarks known at several frames, the fitted one first: ``positions`` [W, L, 3] and each frame's
    Gaussians ``states`` (means [N, 3], quats [N, 4]). Each frame's positions are carried back to the fitted
    frame through the Gaussians nearest them at that frame; the landmarks are bound, as
    :func:`bind_landmarks`, at the per-coordinate median of those (a frame where the reference is off by
    centimetres is outvoted; one where it is unknown is skipped)."""
    fitted = states[0]
    carried_back = [positions[0]] + [carry(bind_landmarks(names, positions[k], *states[k], candidates, anchors, max_distance), *fitted)[0]
                                      for k in range(1, len(states))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a landmark unknown at every frame: NaN, left unbound
        start = np.nanmedian(np.stack(carried_back), axis=0)
    return bind_landmarks(names, start, *fitted, candidates, anchors, max_distance)
