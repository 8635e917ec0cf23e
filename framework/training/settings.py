"""The ``[fit]`` table of a configuration: how the first frame is fitted, and how every dynamics method
fits later frames against the same targets."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import attrs

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.parameters import at_least, between, build_from_table, parameter

from .backdrop import Background, parse_background
from .model import LearningRates

if TYPE_CHECKING:
    from mmcsplat.configuration.config import Config


#: More iterations than any fit needs (weeks of GPU time): a larger value is a typo.
MAX_ITERATIONS = 100_000_000


@attrs.frozen
class FitSettings:
    """The ``[fit]`` table of a configuration."""

    iterations: int = parameter(2000, doc="training iterations, one training camera each", validator=between(1, MAX_ITERATIONS))
    frame: int = parameter(0, doc="the session frame fitted", validator=at_least(0))
    window: int = parameter(0, doc="train on the images of this many frames from `frame` on (a moving camera's capture); 0: one frame "
                                   "on a rig, on a monocular capture the frames that hold 8 images (training.views)", validator=at_least(0))
    seed: int = parameter(0, doc="seed of the initializers and the camera order")
    lambda_image: float = parameter(1.0, doc="weight of the image loss", validator=at_least(0))
    lambda_seg: float = parameter(3.0, doc="weight of the segmentation loss against the masks", validator=at_least(0))
    ssim_weight: float = parameter(0.2, doc="share of D-SSIM in each loss (the rest is L1)", validator=between(0, 1))
    checkpoint_every: int = parameter(500, doc="iterations between atomic checkpoints", validator=at_least(1))
    supersample: int = parameter(1, doc="render at N× and average N × N sub-pixels per pixel (training.supersampling)", validator=at_least(1))
    background: Background = parameter((0.0, 0.0, 0.0), doc='an RGB colour in [0, 1], or "plate": each camera\'s clean plate',
                                       converter=parse_background)
    lrs: LearningRates = parameter(doc="Adam learning rates by parameter", factory=LearningRates)

    @classmethod
    def from_config(cls, config: Config) -> FitSettings:
        """The ``[fit]`` table of ``config``; unknown keys are an error naming the configuration."""
        return cls.from_table(config.get("fit", {}), config.source)

    @classmethod
    def from_table(cls, table: Any, source: str) -> FitSettings:
        """Settings from a ``[fit]`` table read from ``source`` (a configuration, or a run's run.json)."""
        if not isinstance(table, Mapping):
            raise InputError(f"{source}: [fit] must be a table, got {table!r}")
        return build_from_table(cls, table, f"{source}: [fit]")
