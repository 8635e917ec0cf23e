"""Image losses of the fit: L1, SSIM, and the study's photometric mix (1 − λ)·L1 + λ·D-SSIM."""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


@functools.cache
def _gaussian_taps(size: int, sigma: float, dtype: torch.dtype) -> torch.Tensor:
    """The 1D normalised Gaussian whose outer product with itself is the SSIM window."""
    coords = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    return (g / g.sum()).to(dtype)


def ssim_map(image: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM of two [H, W, C] images in [0, 1] (Gaussian window 11, σ 1.5, zero padding as 3DGS).

    The window is separable and zero padding commutes with that, so the five local moments are blurred
    together by two 1D convolutions: the same values as the 11×11 window at a fifth of the cost, which
    matters because the fit computes SSIM twice per iteration."""
    channels = image.shape[-1]
    taps = _gaussian_taps(SSIM_WINDOW, SSIM_SIGMA, image.dtype).to(image.device)
    x = image.permute(2, 0, 1)
    y = target.permute(2, 0, 1)
    moments = torch.cat([x, y, x * x, y * y, x * y])[None]  # [1, 5C, H, W]
    rows = taps.view(1, 1, SSIM_WINDOW, 1).expand(5 * channels, 1, SSIM_WINDOW, 1)
    blurred = F.conv2d(moments, rows, padding=(SSIM_WINDOW // 2, 0), groups=5 * channels)
    blurred = F.conv2d(blurred, rows.transpose(2, 3), padding=(0, SSIM_WINDOW // 2), groups=5 * channels)
    mu_x, mu_y, xx, yy, xy = blurred[0].split(channels)
    sigma_x = xx - mu_x**2
    sigma_y = yy - mu_y**2
    sigma_xy = xy - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + SSIM_C1) * (2 * sigma_xy + SSIM_C2)
    denominator = (mu_x**2 + mu_y**2 + SSIM_C1) * (sigma_x + sigma_y + SSIM_C2)
    return (numerator / denominator).permute(1, 2, 0)


def ssim(image: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of two [H, W, C] images."""
    return ssim_map(image, target).mean()


def photometric_loss(image: torch.Tensor, target: torch.Tensor, ssim_weight: float = 0.2) -> torch.Tensor:
    """(1 − λ)·L1 + λ·(1 − SSIM), the reference study's image loss with λ = 0.2."""
    l1 = (image - target).abs().mean()
    return (1.0 - ssim_weight) * l1 + ssim_weight * (1.0 - ssim(image, target))


def psnr(image: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """PSNR in dB of images in [0, 1], inside ``mask`` [H, W] when given."""
    squared = (image - target) ** 2
    if mask is not None:
        squared = squared[mask]
    return -10.0 * torch.log10(squared.mean().clamp_min(1e-12))
