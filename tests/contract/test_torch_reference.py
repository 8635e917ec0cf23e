"""The oracle's own checks: autograd gradients of torch-reference against finite differences
(torch.autograd.gradcheck), float64 in and out."""

import torch

from mmcsplat.backends.torch_reference import FIELDS, rasterize, rasterize_with_offset
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras
from mmcsplat.testing.renderer_contract import SceneSpec, infant_scene, with_grad


def tiny_scene() -> tuple[Gaussians, RenderCameras]:
    """Four float64 Gaussians in a 20 × 12 image (two tiles across, partial ones), opacities ≤ 0.9 so the
    α cap stays inactive; seeded so no α sits within a finite-difference step of a threshold."""
    g = torch.Generator().manual_seed(7)
    n = 4
    gaussians = Gaussians(
        means=torch.cat([(torch.rand(n, 2, generator=g) - 0.5) * 0.6, 2 + torch.rand(n, 1, generator=g)], 1),
        quats=torch.randn(n, 4, generator=g),
        log_scales=torch.log(0.05 + 0.05 * torch.rand(n, 3, generator=g)),
        opacity_logits=torch.randn(n, generator=g).clamp(-2, 2),
        colors=torch.rand(n, 3, generator=g),
        features=torch.rand(n, 2, generator=g),
    )
    K = torch.tensor([[[20.0, 0.0, 9.7], [0.0, 21.0, 6.2], [0.0, 0.0, 1.0]]])
    return with_grad(gaussians, torch.float64), RenderCameras(K.double(), torch.eye(4, dtype=torch.float64)[None], 20, 12)


def test_gradcheck_every_parameter_and_means2d():
    gaussians, cameras = tiny_scene()
    means2d = torch.zeros(1, gaussians.count, 2, dtype=torch.float64, requires_grad=True)
    background = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)

    def render(*inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = rasterize_with_offset(Gaussians(*inputs[:-1]), cameras, inputs[-1], background)
        return out.rgb, out.features, out.depth, out.alpha

    inputs = (*(getattr(gaussians, f) for f in FIELDS), means2d)
    alpha = render(*inputs)[3].detach()
    assert float(alpha.max()) > 0.5 and float(alpha.min()) == 0.0  # drawn and empty pixels both present
    assert torch.autograd.gradcheck(render, inputs, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=True)


def test_float64_in_float64_out_and_means2d_leaf():
    gaussians, cameras = infant_scene(SceneSpec(50, 24, 16))
    leaves = with_grad(gaussians, torch.float64)
    out = rasterize(leaves, RenderCameras(cameras.K.double(), cameras.viewmats.double(), 24, 16))
    assert {getattr(out, name).dtype for name in ("rgb", "features", "depth", "alpha", "means2d")} == {torch.float64}
    assert out.radii.dtype == torch.int32
    assert out.means2d.is_leaf and out.means2d.requires_grad and not out.means2d.detach().any()
    plain = rasterize(gaussians, cameras)  # no parameter requires grad: nothing to differentiate
    assert not plain.means2d.requires_grad and not plain.rgb.requires_grad
