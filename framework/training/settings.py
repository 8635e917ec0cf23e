"""The ``[fit]`` table of a configuration: how the first frame is fitted, and how every dynamics method
fits later frames against the same targets."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import attrs

from mmcsplat.plugin_api.errors import InputError

from .backdrop import Background, parse_background
from .model import LearningRates

if TYPE_CHECKING:
    from mmcsplat.configuration.config import Config


def _whole_factor(instance: Any, attribute: attrs.Attribute, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InputError(f"fit.{attribute.name} must be a whole number ≥ 1 (sub-pixels per pixel side), got {value!r}")


@attrs.frozen
class FitSettings:
    """The ``[fit]`` table of a configuration."""

    iterations: int = 2000
    frame: int = 0
    seed: int = 0
    lambda_image: float = 1.0
    lambda_seg: float = 3.0
    ssim_weight: float = 0.2
    checkpoint_every: int = 500
    #: Render at N× and average N × N sub-pixels into each pixel, as a camera's pixel integrates over its
    #: area (:mod:`mmcsplat.training.supersampling`); evaluation, tracking and renders of the run do the same.
    supersample: int = attrs.field(default=1, validator=_whole_factor)
    #: An RGB colour, or "plate": each camera's clean plate (:mod:`mmcsplat.training.backdrop`).
    background: Background = attrs.field(default=(0.0, 0.0, 0.0), converter=parse_background)
    lrs: LearningRates = attrs.field(factory=LearningRates, converter=lambda v: v if isinstance(v, LearningRates) else LearningRates(**v))

    @classmethod
    def from_config(cls, config: Config) -> FitSettings:
        """The ``[fit]`` table of ``config``; unknown keys are an error naming the configuration."""
        return cls.from_table(config.get("fit", {}), config.source)

    @classmethod
    def from_table(cls, table: Any, source: str) -> FitSettings:
        """Settings from a ``[fit]`` table read from ``source`` (a configuration, or a run's run.json)."""
        table = dict(table)
        known = {field.name for field in attrs.fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise InputError(f"{source}: unknown [fit] keys {unknown}; known: {sorted(known)}")
        return cls(**table)
