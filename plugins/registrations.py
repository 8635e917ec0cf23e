"""Registers the built-in segmenters, initializers, densifiers, dynamics methods and metrics."""

from __future__ import annotations

from mmcsplat import Registration, hookimpl, needs_modules


@hookimpl
def mmcsplat_metrics() -> list[Registration]:
    return [
        Registration("psnr", "mmcsplat.plugins.metrics:PSNR", "peak signal-to-noise ratio (dB), optionally inside a mask"),
        Registration("ssim", "mmcsplat.plugins.metrics:SSIM", "structural similarity, optionally inside a mask"),
    ]


@hookimpl
def mmcsplat_segmenters() -> list[Registration]:
    segmenters = "mmcsplat.plugins.segmenters"
    return [
        Registration("onnx-semantic", f"{segmenters}.onnx_semantic:OnnxSemanticSegmenter",
                     "any ONNX semantic-segmentation model (a local file and its sidecar) on onnxruntime's CPU",
                     unavailable=needs_modules("onnxruntime")),
        Registration("background", f"{segmenters}.background:BackgroundSegmenter",
                     "OpenCV background subtraction over each camera's sequence (MOG2, KNN or median)"),
        Registration("precomputed", f"{segmenters}.precomputed:PrecomputedSegmenter",
                     "the masks the session already holds (d3dgs, D-NeRF, synthetic ground truth)"),
    ]
