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
def _gaussian_window(size: int, sigma: float, dtype: torch.dtype) -> torch.Tensor:
    coords = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).to(dtype)


def ssim_map(image: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM of two [H, W, C] images in [0, 1] (Gaussian window 11, σ 1.5, zero padding as 3DGS)."""
    channels = image.shape[-1]
    window = _gaussian_window(SSIM_WINDOW, SSIM_SIGMA, image.dtype).to(image.device)
    window = window.expand(channels, 1, SSIM_WINDOW, SSIM_WINDOW)
    x = image.permute(2, 0, 1)[None]
    y = target.permute(2, 0, 1)[None]

    def blur(z: torch.Tensor) -> torch.Tensor:
        return F.conv2d(z, window, padding=SSIM_WINDOW // 2, groups=channels)

    mu_x, mu_y = blur(x), blur(y)
    sigma_x = blur(x * x) - mu_x**2
    sigma_y = blur(y * y) - mu_y**2
    sigma_xy = blur(x * y) - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + SSIM_C1) * (2 * sigma_xy + SSIM_C2)
    denominator = (mu_x**2 + mu_y**2 + SSIM_C1) * (sigma_x + sigma_y + SSIM_C2)
    return (numerator / denominator)[0].permute(1, 2, 0)


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
