"""Backend-specific checks of the ``torch-cpu`` renderer (numba kernels with hand-written backwards).

Agreement with the reference on the contract's scenes is the contract suite's job (tests/contract); here:
exact float64 gradients (gradcheck), the exactness of the contribution-box culling, determinism across
runs and thread counts, concurrent calls, finite results on degenerate input, and compilation caching.
"""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numba
import pytest
import torch

from mmcsplat.backends import cpu_projection, cpu_raster, torch_cpu
from mmcsplat.backends.torch_reference import rasterize as reference_rasterize
from mmcsplat.plugin_api.render_contract import NEAR_PLANE, Gaussians, RenderCameras

FIELDS = ("means", "quats", "log_scales", "opacity_logits", "colors", "features")


def make_scene(n: int, width: int, height: int, cameras: int = 1, seed: int = 0, dtype=torch.float64) -> tuple[Gaussians, RenderCameras]:
    """n random Gaussians (F = 2) in front of ``cameras`` cameras looking down +z, slightly shifted."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) * 2 - 1) * torch.tensor([0.6, 0.45, 0.3]) + torch.tensor([0.0, 0.0, 2.0])
    gaussians = Gaussians(
        means,
        torch.randn(n, 4, generator=g),
        math.log(0.06) + 0.4 * torch.randn(n, 3, generator=g),
        torch.randn(n, generator=g) + 1.0,
        torch.rand(n, 3, generator=g),
        torch.rand(n, 2, generator=g),
    )
    f = 1.2 * width
    K = torch.tensor([[f, 0.0, width / 2 - 0.3], [0.0, 1.1 * f, height / 2 + 0.2], [0.0, 0.0, 1.0]]).expand(cameras, 3, 3).clone()
    viewmats = torch.eye(4).expand(cameras, 4, 4).clone()
    viewmats[:, 0, 3] = torch.linspace(-0.1, 0.1, cameras)
    return leaves(gaussians, dtype), RenderCameras(K.to(dtype), viewmats.to(dtype), width, height)


def leaves(gaussians: Gaussians, dtype=torch.float64) -> Gaussians:
    return Gaussians(*(getattr(gaussians, f).detach().to(dtype).clone().requires_grad_() for f in FIELDS))


def render_and_grads(gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> list[torch.Tensor]:
    """Outputs, then the gradients of a fixed random loss with respect to every parameter and means2d."""
    out = torch_cpu.rasterize(gaussians, cameras, background)
    g = torch.Generator().manual_seed(7)
    images = [out.rgb, out.features, out.depth, out.alpha]
    loss = sum((image * torch.rand(image.shape, generator=g, dtype=image.dtype)).sum() for image in images)
    grads = torch.autograd.grad(loss, [getattr(gaussians, f) for f in FIELDS] + [out.means2d])
    return [image.detach() for image in images] + [out.radii] + list(grads)


def test_gradients_are_exact_in_float64():
    """The hand-written backwards against finite differences, background included (float64 end to end)."""
    gaussians, cameras = make_scene(6, 21, 13, cameras=2, seed=1)
    # plus a large Gaussian beyond 1.3× the field of view whose footprint reaches in: the Jacobian clamp
    extra = Gaussians(torch.tensor([[1.6, 0.0, 2.0]]), torch.tensor([[0.9, 0.1, 0.3, 0.2]]), torch.full((1, 3), math.log(0.6)),
                      torch.tensor([0.5]), torch.tensor([[0.3, 0.6, 0.9]]), torch.tensor([[0.5, 0.5]]))
    gaussians = leaves(Gaussians(*(torch.cat([getattr(gaussians, f).detach(), getattr(extra, f).double()]) for f in FIELDS)))
    background = torch.tensor([[0.2, 0.5, 0.7], [0.9, 0.1, 0.4]], dtype=torch.float64, requires_grad=True)
    params = [getattr(gaussians, f) for f in FIELDS]

    def images(*inputs):
        out = torch_cpu.rasterize(Gaussians(*inputs[:6]), cameras, inputs[6])
        return out.rgb, out.features, out.depth, out.alpha

    assert float(images(*params, background)[3].detach().max()) > 0.5, "the scene must be in view"
    projected = cpu_projection.project_forward(*(t.detach().numpy() for t in (*params[:3], cameras.viewmats, cameras.K)), 21, 13)
    means2d, radii = projected[0], projected[3]
    assert means2d[0, -1, 0] > 1.15 * 21 and radii[0, -1] > 0, "the last Gaussian must be clamped and visible"
    assert torch.autograd.gradcheck(images, (*params, background), fast_mode=True)


def test_contribution_boxes_skip_nothing_the_reference_draws():
    """Pixels outside a Gaussian's box dᵀ·conic·d ≤ 2 ln(255 o) are never visited; the boxes are exact at
    both extremes of opacity (1/255 + ε: a tiny box; 0.999: wider than the 3σ tile rectangle's square)."""
    gaussians, cameras = make_scene(40, 45, 34, seed=2)
    logits = torch.where(torch.arange(40) % 2 == 0, torch.logit(torch.tensor(1 / 255 + 1e-4, dtype=torch.float64)), torch.tensor(6.9, dtype=torch.float64))
    gaussians = leaves(Gaussians(gaussians.means, gaussians.quats, gaussians.log_scales + 0.8, logits, gaussians.colors, gaussians.features))
    ours = torch_cpu.rasterize(gaussians, cameras)
    expected = reference_rasterize(gaussians, cameras)
    for name in ("rgb", "features", "depth", "alpha"):
        assert torch.allclose(getattr(ours, name), getattr(expected, name), atol=1e-12, rtol=0), name
    assert torch.equal(ours.radii, expected.radii)


def test_results_do_not_depend_on_runs_or_thread_count():
    """Gradients are summed per Gaussian in list order, never in thread order: bitwise reproducible."""
    gaussians, cameras = make_scene(300, 70, 50, cameras=3, seed=3, dtype=torch.float32)
    first = render_and_grads(gaussians, cameras)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        single = render_and_grads(gaussians, cameras)
    finally:
        numba.set_num_threads(threads)
    again = render_and_grads(gaussians, cameras)
    for a, b, c in zip(first, single, again):
        assert torch.equal(a, b) and torch.equal(a, c)


def test_concurrent_renders_from_python_threads():
    scenes = [make_scene(200, 40, 30, cameras=2, seed=seed) for seed in range(4)]
    sequential = [render_and_grads(*scene) for scene in scenes]
    with ThreadPoolExecutor(max_workers=4) as pool:
        concurrent = list(pool.map(lambda scene: render_and_grads(*scene), scenes))
    for seq, con in zip(sequential, concurrent):
        assert all(torch.equal(a, b) for a, b in zip(seq, con))


def test_degenerate_gaussians_give_finite_images_and_gradients():
    """Stacked opaque Gaussians on one pixel centre (α cap, early stop), the near plane exactly, absurd
    and vanishing scales, tiny quaternions, a Gaussian far off-axis: nothing may turn into NaN."""
    n = 8
    means = torch.tensor([[0.0, 0.0, 2.0]] * 4 + [[0.0, 0.0, NEAR_PLANE], [0.1, 0.0, 2.0], [0.0, 0.1, 3.0], [40.0, 0.0, 1.0]], dtype=torch.float64)
    log_scales = torch.full((n, 3), math.log(0.05), dtype=torch.float64)
    log_scales[4] = 0.0
    log_scales[5] = torch.tensor([100.0, -30.0, 2.0])
    log_scales[6] = -40.0
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n, dtype=torch.float64)
    quats[6] = torch.tensor([1e-30, 0.0, 2e-30, 0.0])
    gaussians = leaves(Gaussians(means, quats, log_scales, torch.full((n,), 8.0, dtype=torch.float64),
                                 torch.rand(n, 3, dtype=torch.float64), torch.rand(n, 2, dtype=torch.float64)))
    K = torch.tensor([[[50.0, 0.0, 20.0], [0.0, 50.0, 10.0], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    results = render_and_grads(gaussians, RenderCameras(K, torch.eye(4, dtype=torch.float64)[None], 40, 30))
    assert all(torch.isfinite(r).all() for r in results)
    alpha = results[3]
    assert float(alpha[0, 10, 20]) == pytest.approx(1 - (1 - 0.99) ** 2, abs=1e-9), "two capped Gaussians, then the stop"


def test_half_precision_inputs_render_through_the_float32_kernels():
    gaussians, cameras = make_scene(50, 30, 20, dtype=torch.float32)
    full = torch_cpu.rasterize(gaussians, cameras)
    half = torch_cpu.rasterize(leaves(gaussians, torch.bfloat16), cameras)
    assert half.rgb.dtype == torch.bfloat16
    assert torch.allclose(half.rgb.float(), full.rgb.detach(), atol=0.05)
    (half.rgb.float() ** 2).sum().backward()
    assert half.means2d.grad.dtype == torch.bfloat16 and torch.isfinite(half.means2d.grad.float()).all()


def test_kernels_are_cached_and_specialised_once():
    """cache=True on every kernel, and inputs are normalised before the call so that float32 and float64
    renders share one compiled projection and binning (compositing adds one per output dtype)."""
    for dtype in (torch.float32, torch.float64):
        render_and_grads(*make_scene(20, 20, 20, dtype=dtype))
    kernels = {
        cpu_projection.project_forward: 1, cpu_projection.project_backward: 1, cpu_raster.bin_gaussians: 1,
        cpu_raster.composite_forward: 2, cpu_raster.composite_backward: 2,
    }
    for kernel, count in kernels.items():
        assert type(kernel._cache).__name__ == "FunctionCache", f"{kernel.__name__} is not cached on disk"
        assert len(kernel.signatures) == count, f"{kernel.__name__}: {kernel.signatures}"


def test_a_fresh_process_loads_the_kernels_from_the_cache():
    render_and_grads(*make_scene(20, 20, 20, dtype=torch.float32))  # compiled and saved here, if not before
    code = textwrap.dedent(
        """
        import torch
        from mmcsplat.backends import cpu_projection, cpu_raster
        from tests.test_torch_cpu_backend import make_scene, render_and_grads
        render_and_grads(*make_scene(20, 20, 20, dtype=torch.float32))
        kernels = [cpu_projection.project_forward, cpu_projection.project_backward, cpu_raster.bin_gaussians,
                   cpu_raster.composite_forward, cpu_raster.composite_backward]
        print(sum(sum(k.stats.cache_misses.values()) for k in kernels))
        """
    )
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "0", "kernels were recompiled instead of loaded from numba's cache"
