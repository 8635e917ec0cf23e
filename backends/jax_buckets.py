"""Bucketed, cached front end of the JAX rasterizer: static shapes that change rarely.

A training run's Gaussian count drifts every densification step and its Gaussian lists with it. Compiling
:func:`~mmcsplat.backends.jax_raster.rasterize_fixed` for every exact shape would recompile each step, so
:class:`JaxRasterizer` pads the Gaussians to a geometric ladder of sizes (×1.25 by default; padding is
culled through the ``kept`` mask) and sizes the capacity of the Gaussian lists on the same kind of
ladder, with headroom for the padded Gaussians, so that both usually change together; it grows the
capacity (and re-renders) when a scene overflows it and shrinks it only when the load has fallen three
rungs. ``jax.jit`` keeps one compiled program per rung. :attr:`JaxRasterizer.stats` counts XLA
compilations and their time, so a run can show that it does not recompile. Set ``JAX_COMPILATION_CACHE_DIR``
to keep compiled programs across processes.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import attrs
import jax
import jax.numpy as jnp
import numpy as np

from mmcsplat.backends.jax_raster import (
    GAUSSIAN_FIELDS,
    CameraArrays,
    GaussianArrays,
    RasterResult,
    RasterSpec,
    count_blocks,
    rasterize_fixed,
)
from mmcsplat.plugin_api.errors import InputError

_COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "/jax/core/compile/backend_compile_duration",
)


def bucket(n: int, minimum: int, ratio: float) -> int:
    """The smallest rung ≥ ``n`` of the ladder minimum, ⌈minimum·ratio⌉₈, … (each rung rounded up to a
    multiple of 8, and at least 8 above the previous one)."""
    size = minimum
    while size < n:
        size = max(size + 8, math.ceil(size * ratio / 8) * 8)
    return size


@attrs.define
class CompileStats:
    """XLA compilations observed during the rasterizer's calls (including small eager ops, such as the
    padding of a new Gaussian count), their total time (tracing, lowering and compiling), and the renders
    repeated because the Gaussian lists overflowed their capacity."""

    compiles: int = 0
    compile_seconds: float = 0.0
    reruns: int = 0


@attrs.frozen(eq=False)
class Prepared:
    """Gaussians padded to their bucket, with the ``kept`` mask, the real count and the background [C, 3]
    and means2d [C, N_pad, 2] to pass to :func:`rasterize_fixed`."""

    gaussians: GaussianArrays
    background: jax.Array
    means2d: jax.Array
    kept: jax.Array
    count: int


def _forward_vjp(
    gaussians: GaussianArrays, cameras: CameraArrays, background: jax.Array, means2d: jax.Array, kept: jax.Array,
    spec: RasterSpec,
) -> tuple[tuple[jax.Array, ...], Callable, tuple[jax.Array, jax.Array]]:
    """The images and a ``vjp`` function for them (a pytree, so it crosses ``jax.jit``), plus the
    non-differentiable radii and capacity report as auxiliary outputs."""

    def images(gaussians: GaussianArrays, background: jax.Array, means2d: jax.Array):
        result = rasterize_fixed(gaussians, cameras, background, means2d, kept, spec)
        return (result.rgb, result.features, result.depth, result.alpha), (result.radii, result.needed_blocks)

    return jax.vjp(images, gaussians, background, means2d, has_aux=True)


def _apply_vjp(vjp: Callable, cotangents: tuple[jax.Array, ...]) -> tuple[Any, ...]:
    """The gradients of :func:`_forward_vjp`'s inputs for the images' cotangents (jitted on its own)."""
    return vjp(cotangents)


class JaxRasterizer:
    """The JAX rasterizer with bucketed shapes, usable directly from JAX.

    Call it eagerly, inside ``jax.grad`` or ``jax.vjp`` if you like (the capacity check needs concrete
    values, so not inside ``jax.jit``: there, call :func:`rasterize_fixed` with a fixed
    :class:`RasterSpec` and check ``overflow`` yourself). ``ratio`` is the growth factor of the ladders,
    ``block_size`` the slots per list block, ``cell_size`` the side of the pixel cells lists are made for,
    ``min_gaussians`` and ``min_blocks`` the lowest rungs.
    """

    def __init__(
        self, block_size: int = 32, cell_size: int = 8, ratio: float = 1.25, min_gaussians: int = 256, min_blocks: int = 32
    ) -> None:
        if 16 % cell_size:
            raise InputError(f"cell_size must divide the 16-pixel tile, got {cell_size}")
        self.block_size = block_size
        self.cell_size = cell_size
        self.ratio = ratio
        self.min_gaussians = min_gaussians
        self.min_blocks = min_blocks
        self.stats = CompileStats()
        #: The static configuration of the latest render (its ``max_blocks`` is the capacity in use).
        self.last_spec: RasterSpec | None = None
        self._capacity: dict[tuple[int, ...], int] = {}
        options = _compiler_options()
        # Called under jax.grad too, where a jit is nested and takes no compiler options.
        self._render = jax.jit(rasterize_fixed, static_argnames="spec")
        self._count = jax.jit(count_blocks, static_argnames="spec", compiler_options=options)
        self._forward = jax.jit(_forward_vjp, static_argnames="spec", compiler_options=options)
        self._backward = jax.jit(_apply_vjp, compiler_options=options)

    # -- public API -------------------------------------------------------------------------------------

    def __call__(
        self,
        gaussians: GaussianArrays,
        cameras: CameraArrays,
        width: int,
        height: int,
        background: jax.Array | None = None,
        means2d: jax.Array | None = None,
    ) -> RasterResult:
        """Render C cameras; differentiable with ``jax.grad``/``jax.vjp`` with respect to the Gaussians,
        ``background`` ([3] or [C, 3], black when omitted) and ``means2d`` ([C, N, 2], zeros when
        omitted). Returns a :class:`RasterResult` with radii [C, N] for the caller's N."""
        prepared = self.prepare(gaussians, cameras, background, means2d)
        result = self.render_prepared(prepared, cameras, width, height)
        with self._watch():
            return attrs.evolve(result, radii=result.radii[:, : prepared.count])

    def render_prepared(self, prepared: Prepared, cameras: CameraArrays, width: int, height: int) -> RasterResult:
        """Render inputs made by :meth:`prepare`; radii [C, N_pad] (the first ``prepared.count`` are the
        real Gaussians')."""
        with self._watch():
            return self._with_capacity(
                cameras, width, height, prepared,
                lambda spec: self._render(prepared.gaussians, cameras, prepared.background, prepared.means2d, prepared.kept, spec=spec),
                lambda result: result.needed_blocks,
            )

    def forward_with_vjp(
        self, prepared: Prepared, cameras: CameraArrays, width: int, height: int
    ) -> tuple[tuple[jax.Array, ...], Callable, jax.Array]:
        """For bridges to other frameworks: (rgb, features, depth, alpha), a ``vjp`` to pass to
        :meth:`backward` and radii [C, N_pad], on already padded inputs (see :meth:`prepare`)."""
        with self._watch():
            images, vjp, (radii, _) = self._with_capacity(
                cameras, width, height, prepared,
                lambda spec: self._forward(prepared.gaussians, cameras, prepared.background, prepared.means2d, prepared.kept, spec=spec),
                lambda out: out[2][1],
            )
        return images, vjp, radii

    def backward(self, vjp: Callable, cotangents: tuple[jax.Array, ...]) -> tuple[GaussianArrays, jax.Array, jax.Array]:
        """Gradients (Gaussians, background [C, 3], means2d [C, N_pad, 2]) for the cotangents of
        (rgb, features, depth, alpha)."""
        with self._watch():
            return self._backward(vjp, cotangents)

    def padded_size(self, count: int) -> int:
        """The bucket (padded Gaussian count) of ``count`` Gaussians."""
        return bucket(count, self.min_gaussians, self.ratio)

    def prepare(
        self,
        gaussians: GaussianArrays,
        cameras: CameraArrays,
        background: jax.Array | None = None,
        means2d: jax.Array | None = None,
        count: int | None = None,
    ) -> Prepared:
        """Pad the Gaussians (and ``means2d``) to their bucket and broadcast the background to [C, 3].

        ``count`` is the number of real Gaussians when the caller has padded already (rows beyond it are
        culled); padding on the caller's side (e.g. in torch) avoids compiling JAX padding for each new N.
        """
        rows = gaussians.means.shape[0]
        count = rows if count is None else count
        padded = self.padded_size(count)
        num_cameras = cameras.K.shape[0]
        dtype = gaussians.means.dtype
        if rows != padded:
            # An identity rotation keeps the (unused) projection of the padding finite.
            fill = {"quats": jnp.array([1.0, 0.0, 0.0, 0.0], dtype)}
            with self._watch():
                gaussians = GaussianArrays(**{
                    name: _pad_rows(getattr(gaussians, name), padded, fill.get(name))
                    for name in GAUSSIAN_FIELDS
                })
                if means2d is not None:
                    means2d = jnp.pad(means2d, ((0, 0), (0, padded - rows), (0, 0)))
        with self._watch():
            if means2d is None:
                means2d = jnp.zeros((num_cameras, padded, 2), dtype)
            background = jnp.zeros(3, dtype) if background is None else jnp.asarray(background, dtype)
            if background.shape != (num_cameras, 3):
                background = jnp.broadcast_to(background, (num_cameras, 3))
        kept = jnp.asarray(np.arange(padded) < count)
        return Prepared(gaussians, background, means2d, kept, count)

    # -- capacity ---------------------------------------------------------------------------------------

    def _with_capacity(
        self, cameras: CameraArrays, width: int, height: int, prepared: Prepared, run: Callable, needed_of: Callable
    ) -> Any:
        """Run at the remembered capacity; on overflow grow it to the needed rung and run again."""
        padded = prepared.kept.shape[0]
        key = (padded, cameras.K.shape[0], width, height)
        # The load grows with the Gaussians: size a new program for its bucket's largest count.
        headroom = min(padded / max(prepared.count, 1), self.ratio)
        capacity = self._capacity.get(key)
        if capacity is None:
            probe = RasterSpec(width, height, 1, self.block_size, self.cell_size)
            gaussians, cams = jax.lax.stop_gradient((prepared.gaussians, cameras))
            needed = _concrete(self._count(gaussians, cams, prepared.kept, spec=probe))
            capacity = self._rung(needed * headroom)
        while True:
            self.last_spec = RasterSpec(width, height, capacity, self.block_size, self.cell_size)
            out = run(self.last_spec)
            needed = _concrete(needed_of(out))
            if needed <= capacity:
                break
            self.stats.reruns += 1
            capacity = self._rung(needed * headroom)
        if needed * self.ratio**3 < capacity:  # the load fell three rungs: use a cheaper program next time
            capacity = self._rung(needed)
        self._capacity[key] = capacity
        return out

    def _rung(self, needed: float) -> int:
        """The capacity rung for a load of ``needed`` blocks."""
        capacity = bucket(math.ceil(needed), self.min_blocks, self.ratio)
        if capacity * self.block_size >= 2**31:
            raise InputError(f"the Gaussian lists need {needed:.0f} blocks of {self.block_size}: beyond int32 indexing")
        return capacity

    @contextmanager
    def _watch(self) -> Iterator[None]:
        """Add the XLA compilations made inside the block to :attr:`stats`."""
        stats = self.stats

        def listener(event: str, duration: float, **_: Any) -> None:
            if event in _COMPILE_EVENTS:
                stats.compile_seconds += duration
                stats.compiles += event == _COMPILE_EVENTS[-1]

        jax.monitoring.register_event_duration_secs_listener(listener)
        try:
            yield
        finally:
            jax.monitoring.unregister_event_duration_listener(listener)


@functools.cache
def _compiler_options() -> dict[str, Any]:
    """XLA options for the rasterizer's programs: on the CPU, the classic loop emitters compile these
    programs about 30 % faster than the fusion emitters, and run them as fast (measured on scene B).
    Empty where this XLA does not know the option."""
    options = {"xla_cpu_use_fusion_emitters": False}
    if jax.default_backend() != "cpu":
        return {}
    try:
        jax.jit(lambda x: x + 1, compiler_options=options).lower(jnp.zeros(1)).compile()
    except Exception:  # noqa: BLE001 - an XLA that does not know the option: use its defaults
        return {}
    return options


def _pad_rows(x: jax.Array, rows: int, fill: jax.Array | None) -> jax.Array:
    """Pad ``x`` along its first axis to ``rows`` with zeros (or copies of ``fill``)."""
    extra = rows - x.shape[0]
    if fill is None:
        return jnp.pad(x, ((0, extra),) + ((0, 0),) * (x.ndim - 1))
    return jnp.concatenate([x, jnp.broadcast_to(fill, (extra, *x.shape[1:]))])


def _concrete(value: jax.Array) -> int:
    """A capacity figure as a Python int; explains the failure under ``jax.jit``."""
    try:
        return int(value)
    except jax.errors.ConcretizationTypeError as error:
        raise InputError(
            "JaxRasterizer chooses its capacity from the scene and cannot run inside jax.jit; "
            "use mmcsplat.backends.jax_raster.rasterize_fixed with a fixed RasterSpec there"
        ) from error


@functools.cache
def _default_rasterizer() -> JaxRasterizer:
    return JaxRasterizer()


def rasterize(
    gaussians: GaussianArrays,
    cameras: CameraArrays,
    width: int,
    height: int,
    background: jax.Array | None = None,
    means2d: jax.Array | None = None,
) -> RasterResult:
    """Render with a process-wide :class:`JaxRasterizer` (see its ``__call__``)."""
    return _default_rasterizer()(gaussians, cameras, width, height, background, means2d)
