"""A length prior within a body's rigid parts: the Gaussians of one part (a thigh, a forearm, the torso),
found from a skeleton's joints at the first frame, keep their pairwise distances.

Local rigidity holds a neighbourhood of a few centimetres together, so a uniform limb can shorten a
little every frame, each step forgiven by the next frame's neighbours (the Pose2Sim demo's left upper arm
tracked from 284 to 190 mm). An isometry over pairs far apart on one limb forbids that, but pairs that cross
a joint hold it straight (docs/results.md, "First-frame and longer-range rigidity"): pairs are drawn
within a part only.

A part is a group of joints by name; its shape is the segments between its joints (a forearm: elbow to
wrist; the torso: every pair of shoulders and hips). Each foreground Gaussian belongs to the part whose
shape is nearest, if it lies within ``reach`` of it, and to every other part within ``margin`` more: a
Gaussian at a joint belongs to both of its parts, so it keeps its distance to either's far end and the
joint still bends. Both lengths are shares of the skeleton's torso (mid-shoulders to mid-hips), so that an
infant and an adult are treated alike. A skeleton without a neck or a head's centre (MediaPipe's, COCO's
keypoints) gets them between the shoulders and between the ears (``human_skeleton.with_midpoints``), so the
neck part holds the head on the torso.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import attrs
import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.human_skeleton import FEET, HEAD, LIMB_BONES, SYNTHETIC_TORSO, TORSO, TORSO_NAMINGS
from mmcsplat.scene.human_skeleton import torso_length as human_torso_length

from .rigidity import EPSILON, gather_rows
from .rigidity_kernel import Stretch, StretchPairs

#: The neck, base to crown: without it the Gaussians between the torso and the head belong to no part, and
#: on the Pose2Sim demo the tracked head sank 37 mm into the shoulders (docs/results.md, "The neck").
NECK: tuple[str, str] = ("Neck", "Head")
#: Rigid parts of a human body by OpenPose's (and Pose2Sim's) keypoint names and by the synthetic infant's
#: joint names; a part naming joints a skeleton lacks keeps the ones it has (two at least).
HUMAN_PARTS: tuple[tuple[str, ...], ...] = (
    *LIMB_BONES, *FEET, (*TORSO, "Neck"), HEAD, NECK,
    ("shoulder_left", "elbow_left"), ("elbow_left", "wrist_left"), ("shoulder_right", "elbow_right"), ("elbow_right", "wrist_right"),
    ("hip_left", "knee_left"), ("knee_left", "ankle_left"), ("hip_right", "knee_right"), ("knee_right", "ankle_right"),
    SYNTHETIC_TORSO,
)


def _segment_distances(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[P] distances of ``points`` [P, 3] to the segment from ``a`` to ``b``."""
    direction = b - a
    t = np.clip((points - a) @ direction / max(float(direction @ direction), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * direction), axis=-1)


def torso_length(joints: Mapping[str, np.ndarray]) -> float | None:
    """Mid-shoulders to mid-hips, by either naming; ``None`` when the skeleton lacks them."""
    for corners in TORSO_NAMINGS:
        if all(name in joints for name in corners):
            named = dict(zip(TORSO, corners, strict=True))
            return float(human_torso_length(lambda name: joints[named[name]]))
    return None


def part_members(points: np.ndarray, joints: Mapping[str, np.ndarray], parts: Sequence[Sequence[str]], reach: float,
                 margin: float) -> tuple[np.ndarray, list[tuple[str, ...]]]:
    """Which of ``points`` [P, 3] belong to each part: [P, parts] bool over the returned parts (those with two
    joints or more in ``joints``), and those parts' joint names."""
    present = [tuple(name for name in part if name in joints) for part in parts]
    present = [part for part in present if len(part) >= 2]
    if not present:
        return np.zeros((len(points), 0), dtype=bool), []
    distances = np.stack([np.min([_segment_distances(points, joints[a], joints[b]) for i, a in enumerate(part) for b in part[i + 1:]], axis=0)
                          for part in present], axis=1)  # [P, parts]
    nearest = distances.min(axis=1, keepdims=True)
    return (distances <= reach) & (distances <= nearest + margin), present


@attrs.frozen(eq=False)
class PartPairs:
    """Pairs (``first``, ``second``: indices into the model's Gaussians) within one part each, and their
    first-frame ``lengths``; ``parts`` names each part's joints and ``members`` counts its Gaussians."""

    first: torch.Tensor
    second: torch.Tensor
    lengths: torch.Tensor
    parts: tuple[tuple[str, ...], ...]
    members: tuple[int, ...]
    kernel: StretchPairs = attrs.field(init=False, repr=False)

    @kernel.default
    def _kernel(self) -> StretchPairs:
        return StretchPairs.of(self.first, self.second, self.lengths)

    @classmethod
    def build(cls, means: torch.Tensor, foreground: np.ndarray, joints: Mapping[str, np.ndarray], parts: Sequence[Sequence[str]],
              partners: int, reach: float, margin: float, seed: int = 0) -> PartPairs:
        """``partners`` random pairs for each ``foreground`` Gaussian (indices) that belongs to a part, at
        ``means`` (the first frame); ``reach`` and ``margin`` are shares of the skeleton's torso length."""
        torso = torso_length(joints)
        if torso is None or not torso > 0:
            raise InputError("dynamics.skeleton: the joints at the first frame name no shoulders and hips (LShoulder, RShoulder, LHip, "
                             f"RHip, or shoulder_left, … hip_right), so the parts' size is unknown; they name {sorted(joints)}")
        points = means.detach()[torch.as_tensor(foreground)].double().numpy()
        membership, present = part_members(points, joints, parts, reach * torso, margin * torso)
        generator = np.random.default_rng(seed)
        first, second, members = [], [], []
        for part in range(len(present)):
            inside = foreground[membership[:, part]]
            members.append(len(inside))
            if len(inside) < 2:
                continue
            first.append(np.repeat(inside, partners))
            # A random other member: shifting by 1..n−1 never draws the Gaussian itself.
            shift = generator.integers(1, len(inside), size=(len(inside), partners))
            second.append(inside[(np.arange(len(inside))[:, None] + shift) % len(inside)].ravel())
        first_t = torch.as_tensor(np.concatenate(first) if first else np.zeros(0, np.int64))
        second_t = torch.as_tensor(np.concatenate(second) if second else np.zeros(0, np.int64))
        lengths = (means.detach()[first_t] - means.detach()[second_t]).norm(dim=-1)
        return cls(first_t, second_t, lengths, tuple(present), tuple(members))

    def summary(self) -> dict[str, object]:
        """What ``track.json`` records: each part's joints and Gaussians, and the number of pairs."""
        return {"parts": ["–".join(part) for part in self.parts], "gaussians": list(self.members), "pairs": len(self.first)}

    def loss(self, means: torch.Tensor) -> torch.Tensor:
        """Mean over the pairs of |‖μ_i − μ_j‖ − first-frame length| (0 without pairs), in one numba pass
        (:class:`.rigidity_kernel.Stretch`); the value and gradient are :meth:`reference_loss`'."""
        return Stretch.apply(means, self.kernel, EPSILON)

    def reference_loss(self, means: torch.Tensor) -> torch.Tensor:
        """:meth:`loss` in torch operations: the oracle of the numba pass."""
        if not len(self.first):
            return means.sum() * 0
        lengths = (gather_rows(means, self.first) - gather_rows(means, self.second)).norm(dim=-1)
        return torch.sqrt((lengths - self.lengths) ** 2 + EPSILON).mean()
