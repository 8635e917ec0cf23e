"""A regular grid of Gaussians around the scene centre."""

import torch

from mmcsplat.plugin_api.interfaces import Initializer
from mmcsplat.plugin_api.render_contract import Gaussians


class GridInitializer(Initializer):
    def __init__(self, points_per_axis: int = 4, half_size: float = 0.5):
        self.points_per_axis = points_per_axis
        self.half_size = half_size

    def initial_gaussians(self, scene, generator):
        axis = torch.linspace(-self.half_size, self.half_size, self.points_per_axis, dtype=torch.float64)
        grid = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), dim=-1).reshape(-1, 3)
        means = grid + torch.as_tensor(scene.center, dtype=torch.float64)
        n = len(means)
        quats = torch.zeros(n, 4, dtype=torch.float64)
        quats[:, 0] = 1
        return Gaussians(means, quats, torch.full((n, 3), -4.0, dtype=torch.float64), torch.zeros(n, dtype=torch.float64),
                         torch.full((n, 3), 0.5, dtype=torch.float64), torch.zeros(n, 0, dtype=torch.float64))
