"""The renderer contract suite (mmcsplat.testing.renderer_contract) run against every registered renderer
backend; unavailable ones (no CUDA device, a missing extra) are skipped with the registry's reason."""

from mmcsplat.testing.renderer_contract import RendererContract, Tolerance

#: gsplat's CUDA kernels differ from docs/rendering.md in four documented ways (the page's "Backends
#: wrapping another rasterizer", measured on an H100); radii are the page's, computed by the wrapper itself.
GSPLAT = Tolerance(
    forward_atol=2e-2,
    gradient_rtol=5e-2,
    outlier_fraction=0.02,
    deviations=frozenset({"alpha_cap", "tile_cover", "transmittance_from_alpha", "jacobian_clamp"}),
    reason="gsplat caps α at 0.999, covers tiles with opacity-aware 3.33σ boxes instead of 3σ squares, recovers "
    "transmittance from the pixel's float32 α in its backward pass, and clamps the Jacobian at limits taken "
    "from the half-pixel-shifted principal point",
)


class TestRendererContract(RendererContract):
    tolerances = {"torch-cuda": GSPLAT}
