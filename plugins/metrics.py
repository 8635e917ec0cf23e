"""Image-quality metrics."""

from __future__ import annotations

import numpy as np

from mmcsplat.interfaces import Metric


class PSNR(Metric):
    """Peak signal-to-noise ratio in dB for images in [0, 1]; inside ``mask`` only when one is given (the
    reference study's held-out metric is PSNR inside the subject mask)."""

    higher_is_better = True

    def __call__(self, prediction: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> float:
        prediction = np.asarray(prediction, dtype=np.float64)
        target = np.asarray(target, dtype=np.float64)
        if prediction.shape != target.shape:
            raise ValueError(f"psnr: prediction {prediction.shape} and target {target.shape} differ in shape")
        squared = (prediction - target) ** 2
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != target.shape[:2]:
                raise ValueError(f"psnr: mask {mask.shape} does not match image {target.shape[:2]}")
            if not mask.any():
                raise ValueError("psnr: the mask is empty")
            squared = squared[mask]
        mse = float(squared.mean())
        return float("inf") if mse == 0 else float(-10.0 * np.log10(mse))
