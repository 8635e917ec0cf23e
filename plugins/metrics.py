"""Image-quality metrics, computed with the same code as the training losses (mmcsplat.training.losses)."""

from __future__ import annotations

import numpy as np
import torch

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Metric
from mmcsplat.training import losses


def _as_tensors(prediction: np.ndarray, target: np.ndarray, mask: np.ndarray | None, metric: str):
    prediction_t = torch.as_tensor(np.asarray(prediction, dtype=np.float64))
    target_t = torch.as_tensor(np.asarray(target, dtype=np.float64))
    if prediction_t.shape != target_t.shape or prediction_t.dim() != 3:
        raise InputError(f"{metric}: prediction {tuple(prediction_t.shape)} and target {tuple(target_t.shape)} must be equal [H, W, C]")
    if mask is None:
        return prediction_t, target_t, None
    mask_t = torch.from_numpy(np.array(mask, dtype=bool))  # a copy: session frames are read-only
    if tuple(mask_t.shape) != tuple(target_t.shape[:2]):
        raise InputError(f"{metric}: mask {tuple(mask_t.shape)} does not match image {tuple(target_t.shape[:2])}")
    if not mask_t.any():
        raise InputError(f"{metric}: the mask is empty")
    return prediction_t, target_t, mask_t


class PSNR(Metric):
    """Peak signal-to-noise ratio in dB for images in [0, 1]; inside ``mask`` only when one is given (the
    reference study's held-out metric is PSNR inside the subject mask)."""

    def __call__(self, prediction: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> float:
        return float(losses.psnr(*_as_tensors(prediction, target, mask, "psnr")))


class SSIM(Metric):
    """Structural similarity (Gaussian window 11, σ 1.5), averaged inside ``mask`` when one is given."""

    def __call__(self, prediction: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> float:
        prediction_t, target_t, mask_t = _as_tensors(prediction, target, mask, "ssim")
        values = losses.ssim_map(prediction_t, target_t).mean(dim=-1)
        return float(values[mask_t].mean() if mask_t is not None else values.mean())
