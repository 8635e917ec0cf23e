"""The 3DGS rasterizer of docs/rendering.md as one pure, jit-compilable JAX function with static shapes.

:func:`rasterize_fixed` projects, bins and composites C cameras; its shapes are fixed by the Gaussian
count it is given and by a :class:`RasterSpec` (image size and the capacity ``max_blocks`` of the
Gaussian lists). Each Gaussian is listed in the pixel cells (8 × 8 by default) of its 16-pixel tiles where
it can reach α ≥ 1/255; every (cell, Gaussian) pair lands in a block of ``block_size`` slots, and a cell's
depth-sorted list spans consecutive blocks, so no per-tile list length is imposed and the cost follows the
real load. When the lists need more blocks than the capacity, the result says so (``overflow``,
``needed_blocks``) and its images are NaN: a truncated image is never returned as if it were right.
:mod:`mmcsplat.backends.jax_buckets` picks capacities, grows them and re-renders, so callers normally never
see an overflow. docs/jax-backend.md explains the design and its measurements.
"""

from __future__ import annotations

import attrs
import jax
import jax.numpy as jnp

from mmcsplat.backends.jax_composite import composite_blocks
from mmcsplat.plugin_api.render_contract import ALPHA_MIN, DEPTH_EPS, LOW_PASS, NEAR_PLANE, SIGMA_EXTENT, TILE_SIZE

#: Radii are capped here before the int32 cast (a radius this large covers any image anyway).
MAX_RADIUS = 2.0**30


def _pytree(cls: type, data: tuple[str, ...]) -> type:
    """Register an attrs class as a JAX pytree whose leaves are the ``data`` fields."""
    return jax.tree_util.register_dataclass(cls, data_fields=list(data), meta_fields=[])


@attrs.frozen(eq=False)
class GaussianArrays:
    """The Gaussians of :class:`mmcsplat.plugin_api.render_contract.Gaussians` as JAX arrays (same shapes and meaning)."""

    means: jax.Array
    quats: jax.Array
    log_scales: jax.Array
    opacity_logits: jax.Array
    colors: jax.Array
    features: jax.Array


#: The Gaussian fields, in the order of :class:`GaussianArrays` (and of :class:`mmcsplat.plugin_api.render_contract.Gaussians`).
GAUSSIAN_FIELDS = tuple(field.name for field in attrs.fields(GaussianArrays))


@attrs.frozen(eq=False)
class CameraArrays:
    """C pinhole cameras: K [C, 3, 3] and world-to-camera viewmats [C, 4, 4] (OpenCV axes); the image size
    is static and lives in :class:`RasterSpec`."""

    K: jax.Array
    viewmats: jax.Array


@attrs.frozen(eq=False)
class RasterResult:
    """rgb [C, H, W, 3], features [C, H, W, F], depth [C, H, W], alpha [C, H, W], radii [C, N] int32;
    ``needed_blocks`` the list blocks this scene needs and ``overflow`` whether that exceeded the capacity
    (the images are then NaN)."""

    rgb: jax.Array
    features: jax.Array
    depth: jax.Array
    alpha: jax.Array
    radii: jax.Array
    needed_blocks: jax.Array
    overflow: jax.Array


_pytree(GaussianArrays, GAUSSIAN_FIELDS)
_pytree(CameraArrays, ("K", "viewmats"))
_pytree(RasterResult, ("rgb", "features", "depth", "alpha", "radii", "needed_blocks", "overflow"))


@attrs.frozen
class RasterSpec:
    """The static configuration of one compiled rasterizer: image size, capacity ``max_blocks`` of the
    Gaussian lists (blocks of ``block_size`` depth-sorted Gaussians; all cameras share them), and the
    ``cell_size`` (a divisor of 16) of the pixel cells the lists are built for."""

    width: int
    height: int
    max_blocks: int
    block_size: int = 32
    cell_size: int = 8

    @property
    def tiles_x(self) -> int:
        return -(-self.width // TILE_SIZE)

    @property
    def tiles_y(self) -> int:
        return -(-self.height // TILE_SIZE)

    @property
    def cells_x(self) -> int:
        return self.tiles_x * (TILE_SIZE // self.cell_size)

    @property
    def cells_y(self) -> int:
        return self.tiles_y * (TILE_SIZE // self.cell_size)


@attrs.frozen(eq=False)
class _Projected:
    """Per camera and Gaussian ([C, N, ...]): 2D means, conics (a, b, c), depths, opacities [N], integer
    radii, the kept mask and the cells (x0, x1, y0, y1, half-open) whose lists hold the Gaussian."""

    means2d: jax.Array
    conics: jax.Array
    depths: jax.Array
    opacities: jax.Array
    radii: jax.Array
    valid: jax.Array
    cells: jax.Array


_pytree(_Projected, ("means2d", "conics", "depths", "opacities", "radii", "valid", "cells"))


def _rotation_entries(quats: jax.Array) -> list[list[jax.Array]]:
    """[N, 4] (w, x, y, z) quaternions, normalised here, → the 3 × 3 rotation matrix as nested lists of
    [N] arrays. Projection works entry by entry: XLA compiles elementwise code far faster than many tiny
    matrix products, and runs it as fast."""
    w, x, y, z = jnp.moveaxis(quats / jnp.linalg.norm(quats, axis=-1, keepdims=True), -1, 0)
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def project(gaussians: GaussianArrays, cameras: CameraArrays, means2d: jax.Array, kept: jax.Array, spec: RasterSpec) -> _Projected:
    """EWA projection, radii and tile ranges (steps 1–9 of docs/rendering.md); ``kept`` [N] masks out
    padding. Culled entries get finite placeholders so that their gradients are 0, not NaN."""
    view = [[cameras.viewmats[:, i, j, None] for j in range(4)] for i in range(3)]  # [C, 1] entries
    mu = [gaussians.means[None, :, k] for k in range(3)]  # [1, N]
    x, y, z = (sum(view[i][k] * mu[k] for k in range(3)) + view[i][3] for i in range(3))  # [C, N]
    in_front = (z >= NEAR_PLANE) & kept[None, :]
    z = jnp.where(in_front, z, 1.0)

    rot = _rotation_entries(gaussians.quats)
    scales = jnp.exp(gaussians.log_scales)
    rs = [[rot[i][j] * scales[:, j] for j in range(3)] for i in range(3)]  # R S
    wrs = [[sum(view[i][k] * rs[k][j][None] for k in range(3)) for j in range(3)] for i in range(3)]  # W R S

    K = cameras.K
    fx, fy, cx, cy = (v[:, None] for v in (K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]))
    tan_x, tan_y = spec.width / (2 * fx), spec.height / (2 * fy)
    tx = z * jnp.clip(x / z, -(cx / fx + 0.3 * tan_x), (spec.width - cx) / fx + 0.3 * tan_x)
    ty = z * jnp.clip(y / z, -(cy / fy + 0.3 * tan_y), (spec.height - cy) / fy + 0.3 * tan_y)
    # The rows of J W R S, with J = [[fx/z, 0, −fx·tx/z²], [0, fy/z, −fy·ty/z²]]: Σ₂ = (J W R S)(J W R S)ᵀ.
    row_x = [fx / z * wrs[0][j] - fx * tx / (z * z) * wrs[2][j] for j in range(3)]
    row_y = [fy / z * wrs[1][j] - fy * ty / (z * z) * wrs[2][j] for j in range(3)]
    a = sum(r * r for r in row_x) + LOW_PASS
    b = sum(r * s for r, s in zip(row_x, row_y))
    c = sum(r * r for r in row_y) + LOW_PASS
    det = a * c - b * b

    mid = jax.lax.stop_gradient(0.5 * (a + c))
    lambda1 = mid + jnp.sqrt(jnp.maximum(mid * mid - jax.lax.stop_gradient(det), 0.1))
    radii = jnp.ceil(SIGMA_EXTENT * jnp.sqrt(lambda1))
    valid = in_front & (det > 0) & jnp.isfinite(det) & jnp.isfinite(radii)
    det = jnp.where(valid, det, 1.0)
    conics = jnp.stack([c, -b, a], axis=-1) / det[..., None]
    means = jnp.stack([fx * x / z + cx, fy * y / z + cy], axis=-1) + means2d
    radii = jnp.where(valid, jnp.minimum(radii, MAX_RADIUS), 0.0)

    m = jax.lax.stop_gradient(means)
    grid = jnp.array([spec.tiles_x, spec.tiles_y], dtype=m.dtype)
    low = jnp.clip(jnp.floor((m - radii[..., None]) / TILE_SIZE), 0, grid)
    high = jnp.clip(jnp.floor((m + radii[..., None] + TILE_SIZE - 1) / TILE_SIZE), 0, grid)
    valid = valid & jnp.all(high > low, axis=-1)
    radii = jnp.where(valid, radii, 0.0).astype(jnp.int32)

    # A Gaussian is listed in the cells of its tiles where it can reach α ≥ 1/255 at all: inside the
    # ellipse dᵀ Σ₂⁻¹ d ≤ 2 ln(255·o), whose bounding box has half-widths sqrt(2 ln(255·o)·Σ₂ᵢᵢ). Dropping
    # the other (tile, Gaussian) pairs changes nothing (they would be skipped) and saves their work.
    reach = 2 * (jnp.log(1 / ALPHA_MIN) + jax.nn.log_sigmoid(gaussians.opacity_logits))
    half = jnp.sqrt(jax.lax.stop_gradient(jnp.maximum(reach, 0.0)[None, :, None] * jnp.stack([a, c], axis=-1)))
    half = half * (1 + 1e-4) + 1e-2  # a margin for rounding: listing one cell too many is harmless
    per_tile = TILE_SIZE // spec.cell_size
    cell_low = jnp.maximum(jnp.floor((m - half) / spec.cell_size), low * per_tile)
    cell_high = jnp.minimum(jnp.floor((m + half) / spec.cell_size) + 1, high * per_tile)
    cells = jnp.stack([cell_low[..., 0], cell_high[..., 0], cell_low[..., 1], cell_high[..., 1]], axis=-1)
    listed = valid & (reach > 0) & jnp.all(cell_high > cell_low, axis=-1)
    cells = jnp.where(listed[..., None], cells, 0).astype(jnp.int32)
    return _Projected(means, conics, z, jax.nn.sigmoid(gaussians.opacity_logits), radii, valid, cells)


def cell_counts(cells: jax.Array, spec: RasterSpec) -> jax.Array:
    """[C·cells] number of Gaussians listed in each cell (``cells`` [C, N, 4] half-open ranges, empty for
    unlisted Gaussians), cells numbered camera-major then row-major; by summing rectangle corners."""
    num_cameras = cells.shape[0]
    gx, gy = spec.cells_x + 1, spec.cells_y + 1
    x0, x1, y0, y1 = jnp.moveaxis(cells, -1, 0)
    camera = jnp.arange(num_cameras, dtype=jnp.int32)[:, None] * (gx * gy)
    corners = jnp.stack([y0 * gx + x0, y0 * gx + x1, y1 * gx + x0, y1 * gx + x1], axis=-1) + camera[..., None]
    signs = jnp.array([1, -1, -1, 1], dtype=jnp.int32)
    grid = jnp.zeros(num_cameras * gx * gy, jnp.int32).at[corners.reshape(-1)].add(jnp.tile(signs, corners.size // 4))
    grid = jnp.cumsum(jnp.cumsum(grid.reshape(num_cameras, gy, gx), axis=1), axis=2)
    return grid[:, :-1, :-1].reshape(-1)


def needed_blocks(counts: jax.Array, block_size: int) -> jax.Array:
    """Blocks the cell lists of ``counts`` need."""
    return jnp.sum((counts + block_size - 1) // block_size)


def _bin(proj: _Projected, counts: jax.Array, spec: RasterSpec) -> tuple[jax.Array, jax.Array]:
    """Lay the (cell, Gaussian) pairs out in blocks: [max_blocks·L] flat (camera·N + Gaussian) index per
    slot (C·N, the dummy, for empty slots) and [max_blocks] cell of each block (C·cells when unused).
    Within a cell, Gaussians are in front-to-back order: depth ascending, ties by index."""
    num_cameras, n = proj.depths.shape
    per_camera = spec.cells_x * spec.cells_y
    sentinel = num_cameras * per_camera
    slots = spec.max_blocks * spec.block_size
    # Enumerate pairs Gaussian by Gaussian in depth order, then sort them stably by cell.
    order = jnp.argsort(jnp.where(proj.valid, proj.depths, jnp.inf), axis=1, stable=True).astype(jnp.int32)  # [C, N]
    x0, x1, y0, y1 = jnp.take_along_axis(proj.cells, order[..., None], axis=1).reshape(-1, 4).T
    flat = (order + jnp.arange(num_cameras, dtype=order.dtype)[:, None] * n).reshape(-1)
    camera = jnp.repeat(jnp.arange(num_cameras, dtype=jnp.int32), n)
    width, size = x1 - x0, (x1 - x0) * (y1 - y0)
    start = jnp.cumsum(size) - size
    slot = jnp.arange(slots, dtype=jnp.int32)
    # The Gaussian of each slot: the last one starting at or before it (empty ranges start where the next
    # one does, so they are never the last).
    source = jnp.cumsum(jnp.zeros(slots, jnp.int32).at[start].add(1, mode="drop")) - 1
    offset = slot - start[source]
    row, column = jnp.divmod(offset, jnp.maximum(width[source], 1))
    cell = camera[source] * per_camera + (y0[source] + row) * spec.cells_x + x0[source] + column
    cell = jnp.where(slot < start[-1] + size[-1], cell, sentinel)
    span = flat.shape[0]
    if (sentinel + 1) * span < 2**31:  # one packed int32 key sorts several times faster than two operands
        key = jax.lax.sort(cell * span + source)
        cell, member = key // span, flat[key % span]
    else:
        cell, member = jax.lax.sort((cell, flat[source]), num_keys=1, is_stable=True)

    cell_start = jnp.cumsum(counts) - counts
    blocks = (counts + spec.block_size - 1) // spec.block_size
    block_start = jnp.cumsum(blocks) - blocks
    used = cell < sentinel
    safe = jnp.where(used, cell, 0)
    rank = slot - cell_start[safe]
    block = jnp.where(used, block_start[safe] + rank // spec.block_size, spec.max_blocks)
    members = jnp.full(slots, num_cameras * n, jnp.int32).at[block * spec.block_size + rank % spec.block_size].set(member, mode="drop")
    block_cell = jnp.full(spec.max_blocks, sentinel, jnp.int32).at[block].set(cell, mode="drop")
    return members, block_cell


def rasterize_fixed(
    gaussians: GaussianArrays,
    cameras: CameraArrays,
    background: jax.Array,
    means2d: jax.Array,
    kept: jax.Array,
    spec: RasterSpec,
) -> RasterResult:
    """Render C cameras with static shapes (jit with ``spec`` static).

    background [C, 3]; means2d [C, N, 2] added to the projected means (pass zeros and differentiate with
    respect to it for the screen-space gradient); kept [N] bool (False for padding Gaussians, which are
    culled). Differentiable with ``jax.grad``/``jax.vjp`` with respect to every float input. When the
    Gaussian lists need more than ``spec.max_blocks`` blocks, ``overflow`` is True and the images are NaN.
    """
    num_cameras = cameras.K.shape[0]
    num_features = gaussians.features.shape[1]
    proj = project(gaussians, cameras, means2d, kept, spec)
    counts = cell_counts(proj.cells, spec)
    needed = needed_blocks(counts, spec.block_size)
    members, block_cell = _bin(proj, counts, spec)

    n = gaussians.means.shape[0]
    values = jnp.concatenate(
        [
            jnp.broadcast_to(gaussians.colors, (num_cameras, n, 3)),
            jnp.broadcast_to(gaussians.features, (num_cameras, n, num_features)),
            proj.depths[..., None],
        ],
        axis=-1,
    )
    opacities = jnp.broadcast_to(proj.opacities[None, :, None], (num_cameras, n, 1))
    table = jnp.concatenate([proj.means2d, proj.conics, opacities, values], axis=-1).reshape(num_cameras * n, -1)
    table = jnp.concatenate([table, jnp.zeros_like(table[:1])])  # the dummy: opacity 0, never drawn
    splats = table[members].reshape(spec.max_blocks, spec.block_size, -1)

    cs = spec.cell_size
    local = block_cell % (spec.cells_x * spec.cells_y)
    corner = jnp.stack([local % spec.cells_x, local // spec.cells_x], axis=-1) * cs
    offsets = jnp.stack(jnp.meshgrid(jnp.arange(cs), jnp.arange(cs), indexing="xy"), axis=-1).reshape(-1, 2)
    pixels = (corner[:, None, :] + offsets[None]).astype(table.dtype)  # [B, cs², 2] row-major (x, y)
    first = jnp.concatenate([jnp.ones(1, bool), block_cell[1:] != block_cell[:-1]])
    sums, log_t = composite_blocks(splats, pixels, first)
    segments = num_cameras * spec.cells_x * spec.cells_y + 1  # the last one collects unused blocks
    sums = jax.ops.segment_sum(sums, block_cell, segments, indices_are_sorted=True)[:-1]
    log_t = jax.ops.segment_sum(log_t, block_cell, segments, indices_are_sorted=True)[:-1]

    def image(x: jax.Array) -> jax.Array:  # [C·cells, cs², D] → [C, H, W, D]
        x = x.reshape(num_cameras, spec.cells_y, spec.cells_x, cs, cs, -1)
        x = x.transpose(0, 1, 3, 2, 4, 5).reshape(num_cameras, spec.cells_y * cs, spec.cells_x * cs, -1)
        return x[:, : spec.height, : spec.width]

    sums = image(sums)
    log_t = image(log_t[..., None])[..., 0]
    transmittance = jnp.exp(log_t)
    alpha = -jnp.expm1(log_t)  # accurate where little is drawn, which the expected depth divides by
    overflow = needed > spec.max_blocks
    nan = jnp.where(overflow, jnp.nan, 0.0).astype(sums.dtype)
    return RasterResult(
        rgb=sums[..., :3] + transmittance[..., None] * background[:, None, None, :] + nan,
        features=sums[..., 3 : 3 + num_features] + nan,
        depth=sums[..., -1] / jnp.maximum(alpha, DEPTH_EPS) + nan,
        alpha=alpha + nan,
        radii=proj.radii,
        needed_blocks=needed,
        overflow=overflow,
    )


def count_blocks(gaussians: GaussianArrays, cameras: CameraArrays, kept: jax.Array, spec: RasterSpec) -> jax.Array:
    """The blocks :func:`rasterize_fixed` would need (projection and cell counts only; cheap)."""
    means2d = jnp.zeros((cameras.K.shape[0], gaussians.means.shape[0], 2), gaussians.means.dtype)
    proj = project(gaussians, cameras, means2d, kept, spec)
    return needed_blocks(cell_counts(proj.cells, spec), spec.block_size)

