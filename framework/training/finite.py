"""Stopping a training at the first NaN or infinity, naming where it appeared."""

from __future__ import annotations

import torch

from mmcsplat.plugin_api.errors import MmcsplatError
from mmcsplat.plugin_api.render_contract import all_finite
from mmcsplat.scene.gaussian_table import GAUSSIAN_PARAMETERS

from .model import GaussianModel


class FitError(MmcsplatError):
    """A fit that cannot go on (diverged, or every Gaussian pruned away)."""


class NonFiniteError(FitError):
    """A loss, gradient or parameter became NaN or infinite."""


def check_finite(loss: torch.Tensor, model: GaussianModel, step: int, what: str) -> None:
    """Raise :class:`NonFiniteError` at the first NaN/Inf in the loss, or in the Gaussians' ``what``:
    ``"gradient"`` (after ``backward``) or ``"parameter"`` (after the optimiser step)."""
    if not torch.isfinite(loss):
        raise NonFiniteError(f"the loss became {loss.item()} at iteration {step}")
    for name in GAUSSIAN_PARAMETERS:
        value = model.params[name] if what == "parameter" else model.params[name].grad
        if value is not None and not all_finite(value):
            bad = int((~torch.isfinite(value)).reshape(len(value), -1).any(dim=1).sum())
            raise NonFiniteError(f"{what} of {name!r} became non-finite in {bad} Gaussian(s) at iteration {step}")
