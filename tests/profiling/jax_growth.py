"""How often the ``jax`` backend recompiles in a training-like run whose Gaussian count grows slowly.

``python tests/profiling/jax_growth.py [--steps 40] [--growth 0.015]`` starts from bench scene B and,
every step, clones a fraction ``growth`` of the Gaussians (jittered copies, as densification does), then
renders and back-propagates through :class:`~mmcsplat.backends.jax_renderer.JaxRenderer`. It prints, per
step, the Gaussian count, its bucket, the list capacity in use and the compilations so far, then the
totals: an exact-shape jit would compile at every step.
"""

from __future__ import annotations

import argparse
import time

import torch

from mmcsplat.backends.jax_raster import GAUSSIAN_FIELDS
from mmcsplat.backends.jax_renderer import JaxRenderer
from mmcsplat.bench.benchmark import build_scene
from mmcsplat.plugin_api.render_contract import Gaussians


def grow(gaussians: Gaussians, fraction: float, generator: torch.Generator) -> Gaussians:
    """Append jittered clones (2 mm) of a random ``fraction`` of the Gaussians."""
    n = gaussians.count
    picked = torch.randint(n, (max(1, round(n * fraction)),), generator=generator)
    jitter = torch.randn(len(picked), 3, generator=generator) * 0.002
    old = [getattr(gaussians, f) for f in GAUSSIAN_FIELDS]
    new = [old[0][picked] + jitter, *(value[picked] for value in old[1:])]
    return Gaussians(*(torch.cat([a, b]) for a, b in zip(old, new)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--growth", type=float, default=0.015, help="fraction of Gaussians cloned per step")
    args = parser.parse_args(argv)
    scene = build_scene("B")
    renderer = JaxRenderer()
    rasterizer, stats = renderer.rasterizer, renderer.rasterizer.stats
    gaussians, generator = scene.gaussians, torch.Generator().manual_seed(0)
    start = time.perf_counter()
    for step in range(args.steps):
        leaves = Gaussians(*(getattr(gaussians, f).detach().clone().requires_grad_() for f in GAUSSIAN_FIELDS))
        tic = time.perf_counter()
        out = renderer.render(leaves, scene.cameras)
        (out.rgb**2).mean().backward()
        elapsed = time.perf_counter() - tic
        padded, capacity = rasterizer.padded_size(gaussians.count), rasterizer.last_spec.max_blocks
        print(f"step {step:3d}  N {gaussians.count:6d}  bucket {padded:6d}  capacity {capacity:5d} blocks  "
              f"{elapsed:6.2f} s  compiles {stats.compiles:3d} ({stats.compile_seconds:6.1f} s)  reruns {stats.reruns}")
        gaussians = grow(gaussians, args.growth, generator)
    print(f"{args.steps} steps in {time.perf_counter() - start:.1f} s: {stats.compiles} XLA compilations taking "
          f"{stats.compile_seconds:.1f} s, {stats.reruns} re-renders after a capacity overflow")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
