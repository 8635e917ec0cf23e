"""Image losses of the fit: L1, SSIM, and the study's photometric mix (1 − λ)·L1 + λ·D-SSIM."""

from __future__ import annotations

import functools

import attrs
import torch
import torch.nn.functional as F

from mmcsplat.training.ssim_kernel import SSIMMap

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

    On the CPU, numba loops with a written-out gradient (:mod:`.ssim_kernel`: their blur takes a fifth of
    the convolutions' time, and a tracking step about a tenth less, docs/performance.md); elsewhere
    :func:`ssim_map_reference`, their oracle."""
    if image.device.type == "cpu" and target.device.type == "cpu":
        return SSIMMap.apply(image, target, _gaussian_taps(SSIM_WINDOW, SSIM_SIGMA, torch.float64), SSIM_C1, SSIM_C2)
    return ssim_map_reference(image, target)


def ssim_map_reference(image: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """:func:`ssim_map` in torch operations.

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


#: How far around a pixel its SSIM reads.
SSIM_REACH = SSIM_WINDOW // 2


def widened(rows: slice, columns: slice, by: int, height: int, width: int) -> tuple[slice, slice]:
    """The box ``rows`` × ``columns`` widened by ``by`` pixels on every side, clipped to a ``height`` × ``width`` image."""
    return (slice(max(rows.start - by, 0), min(rows.stop + by, height)),
            slice(max(columns.start - by, 0), min(columns.stop + by, width)))


def _integral(values: torch.Tensor) -> torch.Tensor:
    """[H + 1, W + 1] float64 summed-area table of an [H, W] map: any rectangle's sum in four lookups."""
    table = torch.zeros(values.shape[0] + 1, values.shape[1] + 1, dtype=torch.float64)
    table[1:, 1:] = values.double().cumsum(0).cumsum(1)
    return table


@attrs.frozen(eq=False)
class StaticPhotometric:
    """The per-pixel L1 and SSIM of an image that does not change (a view's backdrop alone) against its target,
    as summed-area tables, so that :func:`windowed_photometric_loss` adds to a window's values the rest's."""

    l1: torch.Tensor
    ssim: torch.Tensor
    elements: int

    @classmethod
    def of(cls, image: torch.Tensor, target: torch.Tensor) -> StaticPhotometric:
        """From the unchanging [H, W, C] ``image`` and its ``target``."""
        with torch.no_grad():
            return cls(_integral((image - target).abs().sum(-1)), _integral(ssim_map(image, target).sum(-1)), target.numel())

    @staticmethod
    def outside(table: torch.Tensor, rows: slice, columns: slice) -> torch.Tensor:
        """The table's total less its sum over ``rows`` × ``columns``."""
        inside = table[rows.stop, columns.stop] - table[rows.start, columns.stop] - table[rows.stop, columns.start] + table[rows.start, columns.start]
        return table[-1, -1] - inside


def windowed_photometric_loss(image: torch.Tensor, target: torch.Tensor, static: StaticPhotometric, rows: slice, columns: slice,
                              ssim_weight: float = 0.2) -> torch.Tensor:
    """:func:`photometric_loss` of ``image`` [H, W, C] against ``target``, computed where it can differ from
    ``static``'s image: ``rows`` × ``columns`` must hold every pixel where ``image`` differs from it, widened
    by :data:`SSIM_REACH` (clipped to the image). Equal to the whole image's loss in value and gradient: the
    SSIM of a pixel further out reads only unchanged pixels, and inside, the crop's zero padding sits
    :data:`SSIM_REACH` beyond the window or on the image's own border."""
    height, width = image.shape[:2]
    crop = widened(rows, columns, SSIM_REACH, height, width)
    inner = (slice(rows.start - crop[0].start, rows.stop - crop[0].start), slice(columns.start - crop[1].start, columns.stop - crop[1].start))
    l1 = (image[rows, columns] - target[rows, columns]).abs().sum() + StaticPhotometric.outside(static.l1, rows, columns).to(image.dtype)
    similarity = ssim_map(image[crop], target[crop])[inner].sum() + StaticPhotometric.outside(static.ssim, rows, columns).to(image.dtype)
    return (1.0 - ssim_weight) * l1 / static.elements + ssim_weight * (1.0 - similarity / static.elements)


def psnr(image: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """PSNR in dB of images in [0, 1], inside ``mask`` [H, W] when given."""
    squared = (image - target) ** 2
    if mask is not None:
        squared = squared[mask]
    return -10.0 * torch.log10(squared.mean().clamp_min(1e-12))
