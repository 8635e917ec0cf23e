"""The deformation field of the ``deformation`` dynamics (after Yang et al. 2023): an MLP over sinusoidal
encodings of a Gaussian's canonical centre and the time, giving offsets of its mean, quaternion and
log-scale. The field is per point, so Gaussians added by densification simply get their own encodings."""

from __future__ import annotations

import torch
from torch import nn

from mmcsplat.plugin_api.errors import InputError


def sinusoidal_encoding(x: torch.Tensor, frequencies: int) -> torch.Tensor:
    """[..., D] → [..., D·(1 + 2L)]: ``x`` followed by sin(2ᵏ·x) and cos(2ᵏ·x) for k < L, the NeRF
    positional encoding (no π factor, as NeRF and Deformable-3D-Gaussians use it)."""
    bands = 2.0 ** torch.arange(frequencies, dtype=x.dtype, device=x.device)
    scaled = (x[..., None, :] * bands[:, None]).flatten(-2)  # [..., L·D], band-major
    return torch.cat([x, torch.sin(scaled), torch.cos(scaled)], dim=-1)


class DeformationField(nn.Module):
    """``depth`` fully connected ReLU layers of ``width`` over the encodings of (x, y, z) and t, the input
    concatenated again after layer ``depth // 2`` when ``skip`` (Yang et al.: 8 × 256, skip at layer 4), and
    one linear head giving (Δμ [3], Δq [4], Δs [3]). The head starts at zero, so before training the field
    is the identity: the canonical Gaussians (the first-frame fit) at every time."""

    def __init__(self, depth: int = 4, width: int = 128, frequencies: int = 10, skip: bool = True) -> None:
        super().__init__()
        if depth < 1 or width < 1:
            raise InputError(f"deformation field: depth and width must be positive, got {depth} × {width}")
        self.frequencies = frequencies
        inputs = 4 * (1 + 2 * frequencies)
        self.skip_at = depth // 2 if skip and depth > 1 else None
        sizes = [inputs] + [width] * depth
        self.layers = nn.ModuleList(
            nn.Linear(sizes[i] + (inputs if i == self.skip_at else 0), sizes[i + 1]) for i in range(depth)
        )
        self.head = nn.Linear(width, 10)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, means: torch.Tensor, time: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Offsets (Δμ [N, 3], Δq [N, 4], Δs [N, 3]) of the Gaussians centred at ``means`` [N, 3] at
        ``time`` (a scalar tensor, normalised to [0, 1]). ``means`` is detached: the field moves Gaussians
        but does not pull the canonical centres through its input (as Yang et al.)."""
        xyz = sinusoidal_encoding(means.detach(), self.frequencies)
        t = sinusoidal_encoding(time.reshape(1, 1).to(means.dtype), self.frequencies).expand(len(means), -1)
        encoded = torch.cat([xyz, t], dim=-1)
        hidden = encoded
        for index, layer in enumerate(self.layers):
            if index == self.skip_at:
                hidden = torch.cat([hidden, encoded], dim=-1)
            hidden = torch.relu(layer(hidden))
        out = self.head(hidden)
        return out[:, :3], out[:, 3:7], out[:, 7:]
