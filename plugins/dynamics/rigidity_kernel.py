"""The rigidity and body-part priors' pair sums as numba loops with hand-written gradients.

In torch the priors of a real capture's tracking step (15 280 Gaussians × 20 neighbours, and 122 000
body-part pairs) are some fifty pair-sized tensor operations and their autograd: 35 ms a step on a 2-core
CPU, over a third of the step. Loops over the pairs that compute each sum and its gradient together take
20 ms with their torch glue, and a tracked frame of the Pose2Sim demo a quarter less time. The pure-torch
``reference_losses`` of :class:`~.rigidity.RigidityPrior` and ``reference_loss`` of
:class:`~.body_parts.PartPairs` are the oracles the tests hold these to. The loops are serial: each pair
adds to its neighbour's gradient, which threads over the Gaussians would race for.

Arithmetic is float64 on the CPU whatever the inputs' dtype and device; the losses and gradients return in
the inputs' dtype, on their device. The pairs' constants (indices, reference offsets, lengths, weights)
are converted to that layout once by their owners (:func:`kernel_floats`, :func:`kernel_indices`), not at
every step: at the graph's size the conversions cost 4 ms a step, a fifth of the priors' time.
"""

from __future__ import annotations

import attrs
import numpy as np
import torch
from numba import njit
from torch.autograd.function import once_differentiable

_KERNEL = {"cache": True, "fastmath": False}


@njit(**_KERNEL)
def rigid_rotation_sums(centres, rotations, relative, neighbours, reference, weights, epsilon):  # pragma: no cover - numba
    """Sums over the pairs (f, n = neighbours[f, j]) of sqrt(w·‖Rᵀ(c_n − c_f) − reference‖² + ε) (rigid) and
    sqrt(w·‖q_n − q_f‖² + ε) (rot), with the gradients of each: rigid in centres and rotation matrices, rot
    in ``relative``."""
    count, k = neighbours.shape
    rigid = rot = 0.0
    grad_centres = np.zeros((count, 3))
    grad_rotations = np.zeros((count, 3, 3))
    grad_relative = np.zeros((count, 4))
    for f in range(count):
        r00, r01, r02 = rotations[f, 0, 0], rotations[f, 0, 1], rotations[f, 0, 2]
        r10, r11, r12 = rotations[f, 1, 0], rotations[f, 1, 1], rotations[f, 1, 2]
        r20, r21, r22 = rotations[f, 2, 0], rotations[f, 2, 1], rotations[f, 2, 2]
        cx, cy, cz = centres[f, 0], centres[f, 1], centres[f, 2]
        qw, qx, qy, qz = relative[f, 0], relative[f, 1], relative[f, 2], relative[f, 3]
        # this Gaussian's own gradients, summed over its pairs: centre, rotation matrix, relative
        fx = fy = fz = 0.0
        m00 = m01 = m02 = m10 = m11 = m12 = m20 = m21 = m22 = 0.0
        pw = px = py = pz = 0.0
        for j in range(k):
            n = neighbours[f, j]
            w = weights[f, j]
            ox, oy, oz = centres[n, 0] - cx, centres[n, 1] - cy, centres[n, 2] - cz
            # rigid: the offset rotated back into the reference frame's axes (Rᵀ·offset) against the reference
            bx = r00 * ox + r10 * oy + r20 * oz - reference[f, j, 0]
            by = r01 * ox + r11 * oy + r21 * oz - reference[f, j, 1]
            bz = r02 * ox + r12 * oy + r22 * oz - reference[f, j, 2]
            root = np.sqrt(w * (bx * bx + by * by + bz * bz) + epsilon)
            rigid += root
            scale = w / root
            bx, by, bz = scale * bx, scale * by, scale * bz  # d root / d (Rᵀ·offset)
            gx, gy, gz = r00 * bx + r01 * by + r02 * bz, r10 * bx + r11 * by + r12 * bz, r20 * bx + r21 * by + r22 * bz
            grad_centres[n, 0] += gx
            grad_centres[n, 1] += gy
            grad_centres[n, 2] += gz
            fx -= gx
            fy -= gy
            fz -= gz
            m00 += ox * bx
            m01 += ox * by
            m02 += ox * bz
            m10 += oy * bx
            m11 += oy * by
            m12 += oy * bz
            m20 += oz * bx
            m21 += oz * by
            m22 += oz * bz
            # rot: the neighbour's rotation since the reference against this Gaussian's
            dw, dx, dy, dz = relative[n, 0] - qw, relative[n, 1] - qx, relative[n, 2] - qy, relative[n, 3] - qz
            root = np.sqrt(w * (dw * dw + dx * dx + dy * dy + dz * dz) + epsilon)
            rot += root
            scale = w / root
            grad_relative[n, 0] += scale * dw
            grad_relative[n, 1] += scale * dx
            grad_relative[n, 2] += scale * dy
            grad_relative[n, 3] += scale * dz
            pw -= scale * dw
            px -= scale * dx
            py -= scale * dy
            pz -= scale * dz
        grad_centres[f, 0] += fx
        grad_centres[f, 1] += fy
        grad_centres[f, 2] += fz
        grad_rotations[f, 0, 0], grad_rotations[f, 0, 1], grad_rotations[f, 0, 2] = m00, m01, m02
        grad_rotations[f, 1, 0], grad_rotations[f, 1, 1], grad_rotations[f, 1, 2] = m10, m11, m12
        grad_rotations[f, 2, 0], grad_rotations[f, 2, 1], grad_rotations[f, 2, 2] = m20, m21, m22
        grad_relative[f, 0] += pw
        grad_relative[f, 1] += px
        grad_relative[f, 2] += py
        grad_relative[f, 3] += pz
    return np.array([rigid, rot]), grad_centres, grad_rotations, grad_relative


@njit(**_KERNEL)
def stretch_sum(points, first, second, lengths, weights, epsilon):  # pragma: no cover - numba
    """Sum over the pairs i of sqrt(w_i·(‖p[first_i] − p[second_i]‖ − lengths_i)² + ε), and its gradient in
    ``points``."""
    total = 0.0
    grad = np.zeros(points.shape)
    for i in range(len(first)):
        a, b, w = first[i], second[i], weights[i]
        dx, dy, dz = points[a, 0] - points[b, 0], points[a, 1] - points[b, 1], points[a, 2] - points[b, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        stretch = length - lengths[i]
        root = np.sqrt(w * stretch * stretch + epsilon)
        total += root
        if length > 0.0:
            scale = w * stretch / (root * length)
            grad[a, 0] += scale * dx
            grad[a, 1] += scale * dy
            grad[a, 2] += scale * dz
            grad[b, 0] -= scale * dx
            grad[b, 1] -= scale * dy
            grad[b, 2] -= scale * dz
    return total, grad


def kernel_floats(tensor: torch.Tensor) -> np.ndarray:
    """``tensor`` as the loops read it: a contiguous float64 NumPy array on the CPU (a copy)."""
    return tensor.detach().to(device="cpu", dtype=torch.float64).contiguous().numpy()


def kernel_indices(tensor: torch.Tensor) -> np.ndarray:
    """Integer ``tensor`` as the loops read it: a contiguous int64 NumPy array on the CPU."""
    return tensor.detach().to(device="cpu", dtype=torch.int64).contiguous().numpy()


@attrs.frozen(eq=False)
class StretchPairs:
    """The constants of a :class:`Stretch` sum in the loops' layout: the pairs (``first``, ``second``:
    rows of the points), their rest ``lengths`` and ``weights``."""

    first: np.ndarray
    second: np.ndarray
    lengths: np.ndarray
    weights: np.ndarray

    @classmethod
    def of(cls, first: torch.Tensor, second: torch.Tensor, lengths: torch.Tensor, weights: torch.Tensor | None = None) -> StretchPairs:
        """Converted once from tensors; no ``weights``: every pair weighs 1."""
        return cls(kernel_indices(first), kernel_indices(second), kernel_floats(lengths),
                   np.ones(len(lengths)) if weights is None else kernel_floats(weights))


class RigidRotation(torch.autograd.Function):
    """(rigid, rot) means over a neighbour graph's pairs (:func:`rigid_rotation_sums`), differentiable in
    ``centres`` [F, 3], ``rotations`` [F, 3, 3] and ``relative`` [F, 4] (each Gaussian's rotation since the
    reference frame, as a matrix and as a quaternion); the graph's ``neighbours`` [F, k], ``reference``
    offsets [F, k, 3] and ``weights`` [F, k] are constants, as :func:`kernel_indices` and
    :func:`kernel_floats` give them."""

    @staticmethod
    def forward(ctx, centres, rotations, relative, neighbours: np.ndarray, reference: np.ndarray, weights: np.ndarray,  # noqa: D102 (torch API)
                epsilon: float):
        sums, *grads = rigid_rotation_sums(kernel_floats(centres), kernel_floats(rotations), kernel_floats(relative), neighbours, reference,
                                           weights, float(epsilon))
        ctx.grads = [torch.from_numpy(grad / neighbours.size).to(like) for grad, like in zip(grads, (centres, rotations, relative), strict=True)]
        return torch.from_numpy(sums / neighbours.size).to(centres)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_output):  # noqa: D102 (torch API)
        centres, rotations, relative = ctx.grads
        return grad_output[0] * centres, grad_output[0] * rotations, grad_output[1] * relative, None, None, None, None


class Stretch(torch.autograd.Function):
    """Mean over ``pairs`` of sqrt(w·(‖p_first − p_second‖ − length)² + ε) (:func:`stretch_sum`),
    differentiable in ``points`` [N, 3]."""

    @staticmethod
    def forward(ctx, points, pairs: StretchPairs, epsilon: float):  # noqa: D102 (torch API)
        total, grad = stretch_sum(kernel_floats(points), pairs.first, pairs.second, pairs.lengths, pairs.weights, float(epsilon))
        count = max(len(pairs.first), 1)  # no pairs: a mean of 0 with no gradient
        ctx.grad = torch.from_numpy(grad / count).to(points)
        return points.new_tensor(total / count)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_output):  # noqa: D102 (torch API)
        return grad_output * ctx.grad, None, None
