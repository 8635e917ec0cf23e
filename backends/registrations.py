"""Registers the built-in renderer backends (through the ``mmcsplat`` entry points, like any plugin)."""

from __future__ import annotations

from mmcsplat import Registration, hookimpl, needs_modules


def _cuda_unavailable() -> str | None:
    missing = needs_modules("gsplat", extra="cuda")()
    if missing:
        return missing
    import torch

    return None if torch.cuda.is_available() else "no CUDA device"


@hookimpl
def mmcsplat_renderers() -> list[Registration]:
    return [
        Registration("torch-reference", "mmcsplat.backends.torch_reference:TorchReferenceRenderer",
                     "plain PyTorch, readable, any device and dtype: the test oracle"),
        Registration("torch-cpu", "mmcsplat.backends.torch_cpu:TorchCpuRenderer",
                     "fast CPU path: compiled tile kernels with a hand-written backward",
                     needs_modules("numba")),
        Registration("jax", "mmcsplat.backends.jax_renderer:JaxRenderer",
                     "JAX, jit-compiled with bucketed static shapes", needs_modules("jax", extra="jax")),
        Registration("torch-cuda", "mmcsplat.backends.torch_cuda:GsplatRenderer",
                     "gsplat's CUDA rasterization()", _cuda_unavailable),
    ]
