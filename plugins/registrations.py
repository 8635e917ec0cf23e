"""Registers the built-in segmenters, initializers, densifiers, dynamics methods and metrics."""

from __future__ import annotations

from mmcsplat import Registration, hookimpl


@hookimpl
def mmcsplat_metrics() -> list[Registration]:
    return [
        Registration("psnr", "mmcsplat.plugins.metrics:PSNR", "peak signal-to-noise ratio (dB), optionally inside a mask"),
        Registration("ssim", "mmcsplat.plugins.metrics:SSIM", "structural similarity, optionally inside a mask"),
    ]
