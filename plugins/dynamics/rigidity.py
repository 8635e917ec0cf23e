"""The local-rigidity priors of per-frame tracking (Luiten et al. 2023): a neighbour graph over the
foreground Gaussians, fixed after the first frame, and the rigid, rotation and isometry losses over it.

The rigid and rotation losses compare with a reference frame: the previous one (Luiten's), or the first,
so that a slow slide of Gaussians along a textureless limb adds up to a penalty instead of being forgiven
a frame at a time.

Each loss is the mean over (Gaussian, neighbour) pairs of sqrt(w·‖Δ‖² + 1e-20), w = exp(−λ_w·d²) with d
the pair's first-frame distance (metres): a pair's weight falls to 1/e at d = 1/sqrt(λ_w).
"""

from __future__ import annotations

import attrs
import numpy as np
import torch
from scipy.spatial import cKDTree

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.scene.quaternions import quat_conjugate, quat_multiply, quat_to_rotmat

from .rigidity_kernel import RigidRotation, Stretch, StretchPairs, kernel_floats, kernel_indices

EPSILON = 1e-20


def gather_rows(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``values[index]`` for an integer ``index`` of any shape, through ``index_select``: its backward
    adds rows (index_add) where advanced indexing's scatters with accumulation, 3–4× slower on the CPU at
    the graph's size (15 000 Gaussians × 20 neighbours: 5.8 against 1.5 ms per gather and its gradient)."""
    return torch.index_select(values, 0, index.reshape(-1)).reshape(*index.shape, *values.shape[1:])


@attrs.frozen(eq=False)
class NeighbourGraph:
    """``foreground`` [F] indices of the Gaussians the priors hold together (in the kd-tree's leaf order,
    not ascending); for each, ``neighbours`` [F, k] (positions in ``foreground``), their first-frame
    ``distances`` [F, k] and ``weights`` [F, k]."""

    foreground: torch.Tensor
    neighbours: torch.Tensor
    distances: torch.Tensor
    weights: torch.Tensor

    @classmethod
    def build(cls, means: torch.Tensor, foreground: torch.Tensor, k: int, lambda_w: float, stride: int = 1) -> NeighbourGraph:
        """``k`` foreground neighbours of each ``foreground`` [N] bool Gaussian at ``means``: every
        ``stride``-th of its ``k·stride`` nearest (stride 1: the ``k`` nearest), so a graph reaches further
        at the same cost per step."""
        indices = torch.nonzero(foreground).flatten()
        if len(indices) < 2:
            raise InputError(f"rigidity needs at least two foreground Gaussians (segmentation colour > threshold), found {len(indices)}")
        nearest = min(k * stride, len(indices) - 1)
        tree = cKDTree(means.detach()[indices].double().numpy())
        # The Gaussians in the tree's leaf order, so that neighbours lie close in memory: the pair loops'
        # gathers and scatters then hit the cache (the rigid pass 17 % faster at 16 000 Gaussians).
        order = tree.indices
        position = np.empty_like(order)
        position[order] = np.arange(len(order))
        indices = indices[torch.as_tensor(order)]
        distances, neighbours = tree.query(tree.data[order], k=nearest + 1)  # the first is the point itself
        neighbours = position[neighbours]
        distances = distances.reshape(len(indices), -1)[:, 1::stride]
        neighbours = neighbours.reshape(len(indices), -1)[:, 1::stride]
        distances = torch.as_tensor(distances, dtype=torch.float32)
        neighbours = torch.as_tensor(neighbours, dtype=torch.long)
        return cls(indices, neighbours, distances, torch.exp(-lambda_w * distances**2))


def weighted_distance(a: torch.Tensor, b: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Mean of sqrt(w·‖a − b‖² + 1e-20) over the last dimension's vectors (scalars when a is [F, k])."""
    squared = (a - b) ** 2
    if squared.dim() == weights.dim() + 1:
        squared = squared.sum(-1)
    return torch.sqrt(squared * weights + EPSILON).mean()


class RigidityPrior:
    """The rigid, rotation and isometry losses of the current frame against a reference frame.

    ``remember(means, quats)`` records a frame as the reference (its neighbour offsets and inverse
    rotations): every frame it is given with ``reference="previous"``, the first one only with
    ``reference="first"``; ``losses(means, quats)`` compares the current parameters with it.
    """

    def __init__(self, graph: NeighbourGraph, reference: str = "previous") -> None:
        if reference not in ("previous", "first"):
            raise ValueError(f"reference must be 'previous' or 'first', not {reference!r}")
        self.graph = graph
        self.reference = reference
        self._offsets: torch.Tensor | None = None
        self._inverse: torch.Tensor | None = None
        count, k = graph.neighbours.shape
        self._neighbours = kernel_indices(graph.neighbours)
        self._weights = kernel_floats(graph.weights)
        self._reference: np.ndarray | None = None  # self._offsets as the rigid pass reads it
        self._pairs = StretchPairs.of(torch.arange(count).repeat_interleave(k), graph.neighbours.reshape(-1), graph.distances.reshape(-1),
                                      graph.weights.reshape(-1))  # (Gaussian, neighbour) positions

    def _neighbour_offsets(self, means: torch.Tensor) -> torch.Tensor:
        """[F, k, 3] each foreground Gaussian's offsets to its neighbours."""
        centres = gather_rows(means, self.graph.foreground)
        return gather_rows(centres, self.graph.neighbours) - centres[:, None]

    def _rotations(self, quats: torch.Tensor) -> torch.Tensor:
        """[F, 4] the foreground Gaussians' unit rotations."""
        rotations = gather_rows(quats, self.graph.foreground)
        return rotations / rotations.norm(dim=-1, keepdim=True)

    def _since_reference(self, quats: torch.Tensor) -> torch.Tensor:
        """[F, 4] each foreground Gaussian's rotation since the reference frame."""
        if self._offsets is None or self._inverse is None:
            raise RuntimeError("RigidityPrior.remember() must record a previous frame first")
        return quat_multiply(self._rotations(quats), self._inverse)

    def remember(self, means: torch.Tensor, quats: torch.Tensor) -> None:
        """Make ``means``/``quats`` the frame the next losses compare against (with ``reference="first"``,
        only the first frame given)."""
        if self.reference == "first" and self._offsets is not None:
            return
        with torch.no_grad():
            self._offsets = self._neighbour_offsets(means)
            self._inverse = quat_conjugate(self._rotations(quats))
        self._reference = kernel_floats(self._offsets)

    def losses(self, means: torch.Tensor, quats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(rigid, rot, iso): neighbour offsets rotated back into the reference frame's local axes versus
        the reference offsets; rotations since the reference versus the neighbours'; neighbour distances
        versus the first frame's. The pairs are numba passes (:mod:`.rigidity_kernel`); the values and
        gradients are :meth:`reference_losses`'."""
        graph = self.graph
        relative = self._since_reference(quats)
        centres = gather_rows(means, graph.foreground)
        rigid, rot = RigidRotation.apply(centres, quat_to_rotmat(relative), relative, self._neighbours, self._reference, self._weights,
                                         EPSILON).unbind()
        iso = Stretch.apply(centres, self._pairs, EPSILON)
        return rigid, rot, iso

    def reference_losses(self, means: torch.Tensor, quats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`losses` in torch operations: the oracle of the numba pass."""
        graph = self.graph
        relative = self._since_reference(quats)
        offsets = self._neighbour_offsets(means)
        back = torch.einsum("fji,fkj->fki", quat_to_rotmat(relative), offsets)  # Rᵀ·offset
        rigid = weighted_distance(back, self._offsets, graph.weights)
        rot = weighted_distance(gather_rows(relative, graph.neighbours), relative[:, None], graph.weights)
        iso = weighted_distance(offsets.norm(dim=-1), graph.distances, graph.weights)
        return rigid, rot, iso
