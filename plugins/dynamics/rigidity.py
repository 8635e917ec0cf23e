"""The local-rigidity priors of per-frame tracking (Luiten et al. 2023): a neighbour graph over the
foreground Gaussians, fixed after the first frame, and the rigid, rotation and isometry losses over it.

Each loss is the mean over (Gaussian, neighbour) pairs of sqrt(w·‖Δ‖² + 1e-20), w = exp(−λ_w·d²) with d
the pair's first-frame distance (metres): a pair's weight falls to 1/e at d = 1/sqrt(λ_w).
"""

from __future__ import annotations

import attrs
import torch
from scipy.spatial import cKDTree

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.quaternions import quat_conjugate, quat_multiply, quat_to_rotmat

EPSILON = 1e-20


@attrs.frozen(eq=False)
class NeighbourGraph:
    """``foreground`` [F] indices of the Gaussians the priors hold together; for each, ``neighbours``
    [F, k] (positions in ``foreground``), their first-frame ``distances`` [F, k] and ``weights`` [F, k]."""

    foreground: torch.Tensor
    neighbours: torch.Tensor
    distances: torch.Tensor
    weights: torch.Tensor

    @classmethod
    def build(cls, means: torch.Tensor, foreground: torch.Tensor, k: int, lambda_w: float) -> NeighbourGraph:
        """The ``k`` nearest foreground neighbours of each ``foreground`` [N] bool Gaussian at ``means``."""
        indices = torch.nonzero(foreground).flatten()
        if len(indices) < 2:
            raise InputError(f"rigidity needs at least two foreground Gaussians (segmentation colour > threshold), found {len(indices)}")
        k = min(k, len(indices) - 1)
        points = means.detach()[indices].double().numpy()
        distances, neighbours = cKDTree(points).query(points, k=k + 1)  # the first is the point itself
        distances = torch.as_tensor(distances[:, 1:], dtype=torch.float32).reshape(len(indices), k)
        neighbours = torch.as_tensor(neighbours[:, 1:], dtype=torch.long).reshape(len(indices), k)
        return cls(indices, neighbours, distances, torch.exp(-lambda_w * distances**2))


def weighted_distance(a: torch.Tensor, b: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Mean of sqrt(w·‖a − b‖² + 1e-20) over the last dimension's vectors (scalars when a is [F, k])."""
    squared = (a - b) ** 2
    if squared.dim() == weights.dim() + 1:
        squared = squared.sum(-1)
    return torch.sqrt(squared * weights + EPSILON).mean()


class RigidityPrior:
    """The rigid, rotation and isometry losses of the current frame against the previous one.

    ``remember(means, quats)`` records a frame as "previous" (its neighbour offsets and inverse
    rotations); ``losses(means, quats)`` compares the current parameters with it.
    """

    def __init__(self, graph: NeighbourGraph) -> None:
        self.graph = graph
        self._offsets: torch.Tensor | None = None
        self._inverse: torch.Tensor | None = None

    def _offsets_and_rotations(self, means: torch.Tensor, quats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        index = self.graph.foreground
        centres = means[index]
        offsets = centres[self.graph.neighbours] - centres[:, None]  # [F, k, 3]
        rotations = quats[index] / quats[index].norm(dim=-1, keepdim=True)
        return offsets, rotations

    def remember(self, means: torch.Tensor, quats: torch.Tensor) -> None:
        """Make ``means``/``quats`` the previous frame the next losses compare against."""
        with torch.no_grad():
            offsets, rotations = self._offsets_and_rotations(means, quats)
        self._offsets = offsets
        self._inverse = quat_conjugate(rotations)

    def losses(self, means: torch.Tensor, quats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(rigid, rot, iso): neighbour offsets rotated back into the previous frame's local axes versus
        the previous offsets; relative rotations versus the neighbours'; neighbour distances versus the
        first frame's."""
        if self._offsets is None or self._inverse is None:
            raise RuntimeError("RigidityPrior.remember() must record a previous frame first")
        graph = self.graph
        offsets, rotations = self._offsets_and_rotations(means, quats)
        relative = quat_multiply(rotations, self._inverse)  # [F, 4]: rotation since the previous frame
        back = torch.einsum("fji,fkj->fki", quat_to_rotmat(relative), offsets)  # Rᵀ·offset
        rigid = weighted_distance(back, self._offsets, graph.weights)
        rot = weighted_distance(relative[graph.neighbours], relative[:, None], graph.weights)
        iso = weighted_distance(offsets.norm(dim=-1), graph.distances, graph.weights)
        return rigid, rot, iso
