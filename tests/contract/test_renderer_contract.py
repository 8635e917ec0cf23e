"""The renderer contract suite (mmcsplat.testing.renderer_contract) run against every registered renderer
backend; unavailable ones (no CUDA device, a missing extra) are skipped with the registry's reason."""

from mmcsplat.testing.renderer_contract import RendererContract, Tolerance

#: gsplat's CUDA kernels fix two constants differently from docs/rendering.md (see the page's
#: "Backends wrapping another rasterizer"); radii are the page's, computed by the wrapper itself.
GSPLAT = Tolerance(
    forward_atol=2e-2,
    gradient_rtol=5e-2,
    outlier_fraction=0.02,
    deviations=frozenset({"alpha_cap"}),
    reason="gsplat caps α at 0.999 and covers tiles with opacity-aware 3.33σ boxes instead of 3σ squares",
)


class TestRendererContract(RendererContract):
    tolerances = {"torch-cuda": GSPLAT}
