"""The order training cameras are visited in."""

from __future__ import annotations

import torch


class CameraSchedule:
    """Cameras in random order without replacement, one block (a permutation) at a time."""

    def __init__(self, count: int, generator: torch.Generator) -> None:
        self.count = count
        self.generator = generator
        self.queue: list[int] = []

    def next(self) -> int:
        """The index of the next camera."""
        if not self.queue:
            self.queue = torch.randperm(self.count, generator=self.generator).tolist()
        return self.queue.pop()
