"""The torch-cuda wrapper's glue (half-pixel shift, channel packing, backgrounds, depth, radii, means2d),
checked without a GPU: a stand-in for ``gsplat.rasterization`` with gsplat's documented conventions
(pixel centres at (u + 0.5, v + 0.5), colour channels plus expected depth last, backgrounds over the
colour channels, alphas [C, H, W, 1], ``meta["means2d"]``), computed by torch-reference on the CPU. The
contract suite then runs against GsplatRenderer(device="cpu"). gsplat's own kernels are tested by the
contract suite on a machine with a CUDA device (torch-cuda in test_renderer_contract.py)."""

import sys
import types

import pytest
import torch

from mmcsplat.backends.torch_cuda import GsplatRenderer
from mmcsplat.backends.torch_reference import rasterize_with_offset
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras
from mmcsplat.testing.renderer_contract import RendererContract


def fake_rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, *, near_plane,
                       eps2d, packed, tile_size, backgrounds, render_mode, absgrad, rasterize_mode):
    assert (near_plane, eps2d, packed, tile_size, render_mode, absgrad, rasterize_mode) == (
        0.01, 0.3, False, 16, "RGB+ED", False, "classic")
    assert all(t.dtype == torch.float32 for t in (means, quats, scales, opacities, colors, viewmats, Ks, backgrounds))
    K = Ks.clone()
    K[:, :2, 2] -= 0.5  # gsplat samples pixel (u, v) at (u + 0.5, v + 0.5)
    gaussians = Gaussians(means, quats, torch.log(scales), torch.logit(opacities), colors[:, :3], colors[:, 3:])
    leaf = torch.zeros(len(viewmats), len(means), 2, requires_grad=torch.is_grad_enabled() and means.requires_grad)
    means2d = leaf.clone()  # gsplat's means2d is a non-leaf of the graph, upstream of the images
    out = rasterize_with_offset(gaussians, RenderCameras(K, viewmats, width, height), means2d)
    channels = torch.cat([out.rgb, out.features], -1) + (1 - out.alpha)[..., None] * backgrounds[:, None, None, :]
    return torch.cat([channels, out.depth[..., None]], -1), out.alpha[..., None], {"means2d": means2d, "radii": out.radii}


class TestGsplatGlue(RendererContract):
    renderers = ["torch-cuda"]

    @pytest.fixture
    def renderer(self, monkeypatch):
        monkeypatch.setitem(sys.modules, "gsplat", types.SimpleNamespace(rasterization=fake_rasterization))
        return GsplatRenderer(device="cpu")

    # The stand-in is torch-reference itself: the large seeded scenes add time, not coverage of the glue.
    @pytest.mark.parametrize("n", [10])
    def test_forward_matches_reference(self, renderer, tolerance, n):
        super().test_forward_matches_reference(renderer, tolerance, n)

    @pytest.mark.parametrize("n", [10])
    def test_gradients_match_reference(self, renderer, tolerance, n):
        super().test_gradients_match_reference(renderer, tolerance, n)
