"""Metric plugins and the losses they share."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mmcsplat.configuration.registry import default_registry
from mmcsplat.training import losses


def test_psnr_known_values_and_mask():
    psnr = default_registry().create("metric", "psnr")
    target = np.zeros((4, 4, 3))
    prediction = np.full((4, 4, 3), 0.1)
    assert psnr(prediction, target) == pytest.approx(20.0)
    mask = np.zeros((4, 4), dtype=bool)
    mask[0, 0] = True
    prediction[1:, :] = 1.0  # errors outside the mask do not count
    assert psnr(prediction, target, mask) == pytest.approx(20.0)
    with pytest.raises(ValueError, match="mask is empty"):
        psnr(prediction, target, np.zeros((4, 4), dtype=bool))
    with pytest.raises(ValueError, match="shape|must be equal"):
        psnr(prediction[:2], target)


def test_ssim_identity_and_degradation():
    ssim = default_registry().create("metric", "ssim")
    rng = np.random.default_rng(0)
    image = rng.random((32, 40, 3))
    assert ssim(image, image) == pytest.approx(1.0)
    noisy = np.clip(image + rng.normal(0, 0.2, image.shape), 0, 1)
    assert ssim(noisy, image) < 0.9


def test_ssim_map_equals_the_full_11x11_window():
    """The separable blur is an optimisation: it must match SSIM computed with the 2D window directly."""
    generator = torch.Generator().manual_seed(1)
    image, target = torch.rand(2, 23, 31, 3, generator=generator, dtype=torch.float64)
    coords = torch.arange(11, dtype=torch.float64) - 5
    taps = torch.exp(-coords**2 / (2 * 1.5**2))
    window = (taps[:, None] * taps[None, :] / taps.sum() ** 2).expand(3, 1, 11, 11)

    def blur(z):
        return torch.nn.functional.conv2d(z.permute(2, 0, 1)[None], window, padding=5, groups=3)[0].permute(1, 2, 0)

    mu_x, mu_y = blur(image), blur(target)
    var_x, var_y, cov = blur(image**2) - mu_x**2, blur(target**2) - mu_y**2, blur(image * target) - mu_x * mu_y
    c1, c2 = 0.01**2, 0.03**2
    expected = (2 * mu_x * mu_y + c1) * (2 * cov + c2) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    torch.testing.assert_close(losses.ssim_map(image, target), expected, rtol=1e-10, atol=1e-12)


def test_photometric_loss_gradient_points_to_target():
    target = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    image = (target + 0.1).clamp(0, 1).requires_grad_()
    loss = losses.photometric_loss(image, target)
    loss.backward()
    assert loss.item() > 0
    assert torch.autograd.gradcheck(lambda x: losses.photometric_loss(x, target), (image.detach().clone().requires_grad_(),))
