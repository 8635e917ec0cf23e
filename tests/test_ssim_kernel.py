"""The numba SSIM (mmcsplat.training.ssim_kernel) against its torch oracle, losses.ssim_map_reference."""

from __future__ import annotations

import pytest
import torch

from mmcsplat.training import losses


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("shape", [(23, 31, 3), (4, 9, 1), (40, 17, 2), (1, 1, 3)])
def test_the_kernel_matches_the_torch_ssim_in_value_and_both_gradients(shape, dtype):
    generator = torch.Generator().manual_seed(sum(shape))
    image, target = torch.rand(2, *shape, generator=generator, dtype=torch.float64).to(dtype)
    weights = torch.rand(shape, generator=generator, dtype=torch.float64).to(dtype)  # an arbitrary upstream gradient
    results = []
    for ssim_map in (losses.ssim_map, losses.ssim_map_reference):
        x, y = image.clone().requires_grad_(), target.clone().requires_grad_()
        value = ssim_map(x, y)
        (value * weights).sum().backward()
        results.append((value.detach(), x.grad, y.grad))
    tolerance = {"rtol": 1e-10, "atol": 1e-12} if dtype == torch.float64 else {"rtol": 1e-4, "atol": 1e-5}
    for kernel, reference in zip(*results, strict=True):
        assert kernel.dtype == dtype
        torch.testing.assert_close(kernel, reference, **tolerance)


def test_the_kernel_gradient_is_the_derivative():
    generator = torch.Generator().manual_seed(3)
    image, target = torch.rand(2, 13, 15, 3, generator=generator, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda x, y: losses.ssim_map(x, y), (image.requires_grad_(), target.requires_grad_()))


def test_a_target_without_gradient_and_a_strided_crop():
    """The training loss passes crops of larger images (strided views) and a target that needs no gradient."""
    generator = torch.Generator().manual_seed(4)
    image = torch.rand(30, 40, 3, generator=generator).requires_grad_()
    target = torch.rand(30, 40, 3, generator=generator)
    crop = (slice(3, 27), slice(5, 33))
    kernel = losses.ssim_map(image[crop], target[crop]).sum()
    (grad,) = torch.autograd.grad(kernel, image)
    reference = losses.ssim_map_reference(image[crop], target[crop]).sum()
    (expected,) = torch.autograd.grad(reference, image)
    torch.testing.assert_close(kernel, reference, rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(grad, expected, rtol=1e-4, atol=1e-5)


def test_half_precision_computes_in_float32():
    image, target = torch.rand(2, 12, 12, 3, generator=torch.Generator().manual_seed(5))
    value = losses.ssim_map(image.to(torch.bfloat16), target.to(torch.bfloat16))
    assert value.dtype == torch.bfloat16
    torch.testing.assert_close(value.float(), losses.ssim_map_reference(image.to(torch.bfloat16).float(), target.to(torch.bfloat16).float()),
                               rtol=1e-2, atol=1e-2)
