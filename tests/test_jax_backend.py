"""The JAX backend's own guarantees: use from pure JAX with jax.grad, no recompilation for Gaussian counts
within a bucket, the DLPack crossing, and capacity overflow handled, never rendered silently.

(Agreement with torch-reference on the contract's scenes is the contract suite's job, tests/contract/.)
Compiles are slow, so every test shares one rasterizer and one image size."""

from __future__ import annotations

import numpy as np
import pytest
import torch

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

from mmcsplat.backends.jax_buckets import JaxRasterizer, bucket  # noqa: E402
from mmcsplat.backends.jax_raster import CameraArrays, GaussianArrays, RasterSpec, rasterize_fixed  # noqa: E402
from mmcsplat.backends.jax_renderer import JaxRenderer, to_jax, to_torch  # noqa: E402
from mmcsplat.backends.torch_reference import rasterize as reference  # noqa: E402
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras  # noqa: E402

WIDTH, HEIGHT = 40, 24  # 3 × 2 tiles, the last column partial
FIELDS = ("means", "quats", "log_scales", "opacity_logits", "colors", "features")


def scene(n: int, seed: int = 0, depth: float = 2.0) -> dict[str, np.ndarray]:
    """n Gaussians in front of the camera of :func:`camera`, float64 arrays by field name."""
    rng = np.random.default_rng(seed)
    return {
        "means": np.c_[rng.uniform(-0.5, 0.5, n), rng.uniform(-0.3, 0.3, n), depth + rng.uniform(-0.2, 0.2, n)],
        "quats": rng.normal(size=(n, 4)),
        "log_scales": np.log(rng.uniform(0.02, 0.08, (n, 3))),
        "opacity_logits": rng.normal(size=n),
        "colors": rng.uniform(size=(n, 3)),
        "features": rng.uniform(size=(n, 2)),
    }


def camera() -> tuple[np.ndarray, np.ndarray]:
    """K [1, 3, 3] (fx ≠ fy, off-centre principal point) and an identity viewmat [1, 4, 4]."""
    K = np.array([[[40.0, 0.0, 19.0], [0.0, 42.0, 12.5], [0.0, 0.0, 1.0]]])
    return K, np.eye(4)[None]


def as_jax(arrays: dict[str, np.ndarray]) -> GaussianArrays:
    return GaussianArrays(**{f: jnp.asarray(arrays[f], jnp.float32) for f in FIELDS})


def as_torch(arrays: dict[str, np.ndarray], dtype: torch.dtype) -> Gaussians:
    return Gaussians(*(torch.tensor(arrays[f], dtype=dtype, requires_grad=True) for f in FIELDS))


def jax_cameras() -> CameraArrays:
    K, viewmats = camera()
    return CameraArrays(jnp.asarray(K, jnp.float32), jnp.asarray(viewmats, jnp.float32))


def torch_cameras(dtype: torch.dtype) -> RenderCameras:
    K, viewmats = camera()
    return RenderCameras(torch.tensor(K, dtype=dtype), torch.tensor(viewmats, dtype=dtype), WIDTH, HEIGHT)


@pytest.fixture(scope="module")
def rasterizer() -> JaxRasterizer:
    return JaxRasterizer()


@pytest.fixture(scope="module")
def renderer() -> JaxRenderer:
    return JaxRenderer()


def weights(seed: int = 1) -> dict[str, np.ndarray]:
    """Fixed random weights of a linear loss over every output."""
    rng = np.random.default_rng(seed)
    return {name: rng.uniform(size=shape) for name, shape in
            (("rgb", (1, HEIGHT, WIDTH, 3)), ("features", (1, HEIGHT, WIDTH, 2)), ("depth", (1, HEIGHT, WIDTH)), ("alpha", (1, HEIGHT, WIDTH)))}


def test_pure_jax_gradients_match_the_reference(rasterizer: JaxRasterizer) -> None:
    arrays, w = scene(24), weights()
    background = np.array([0.1, 0.5, 0.9])

    def loss(gaussians: GaussianArrays, background: jax.Array, means2d: jax.Array) -> jax.Array:
        out = rasterizer(gaussians, jax_cameras(), WIDTH, HEIGHT, background, means2d)
        return sum(jnp.sum(getattr(out, name) * w[name]) for name in w)

    means2d = jnp.zeros((1, 24, 2), jnp.float32)
    value, (grads, grad_background, grad_means2d) = jax.value_and_grad(loss, argnums=(0, 1, 2))(
        as_jax(arrays), jnp.asarray(background, jnp.float32), means2d
    )

    gaussians = as_torch(arrays, torch.float64)
    background_t = torch.tensor(background, requires_grad=True)
    out = reference(gaussians, torch_cameras(torch.float64), background_t)
    expected = sum((getattr(out, name) * torch.tensor(w[name])).sum() for name in w)
    expected.backward()
    assert float(value) == pytest.approx(float(expected.detach()), rel=1e-5)
    pairs = [(getattr(grads, f), getattr(gaussians, f).grad) for f in FIELDS]
    pairs += [(grad_background, background_t.grad), (grad_means2d, out.means2d.grad)]
    for actual, reference_grad in pairs:
        error = np.linalg.norm(np.asarray(actual) - reference_grad.numpy()) / np.linalg.norm(reference_grad.numpy())
        assert error < 1e-3


def test_no_recompilation_within_a_bucket(renderer: JaxRenderer) -> None:
    stats = renderer.rasterizer.stats
    cameras = torch_cameras(torch.float32)

    def step(n: int) -> None:
        out = renderer.render(as_torch(scene(n, seed=n), torch.float32), cameras)
        (out.rgb.sum() + out.depth.sum()).backward()
        assert out.means2d.grad is not None and bool(out.means2d.grad.abs().sum() > 0)

    step(200)  # compiles the 256-Gaussian bucket
    before = stats.compiles
    compiled: list[str] = []  # every XLA compilation in the process, not only those the rasterizer counts

    def listener(event: str, duration: float, **_: object) -> None:
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(event)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        for n in (201, 230, 256):
            step(n)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert not compiled and stats.compiles == before, "a Gaussian count within the bucket recompiled"
    with torch.no_grad():  # the next bucket is a new program (forward-only here: cheaper to compile)
        renderer.render(as_torch(scene(257), torch.float32), cameras)
    assert stats.compiles > before


def test_bucket_ladder() -> None:
    ladder = [bucket(n, 256, 1.25) for n in (0, 256, 257, 320, 321, 10_000)]
    assert ladder[:5] == [256, 256, 320, 320, 400]
    assert 10_000 <= ladder[5] < 12_500 and ladder[5] % 8 == 0


def test_dlpack_round_trip_shares_memory() -> None:
    tensor = torch.arange(12, dtype=torch.float32).reshape(3, 4)
    array = to_jax(tensor)
    assert array.unsafe_buffer_pointer() == tensor.data_ptr(), "torch → JAX copied"
    back = to_torch(array * 2, torch.device("cpu"))
    assert torch.equal(back, tensor * 2)
    result = jnp.arange(6.0)
    assert to_torch(result, torch.device("cpu")).data_ptr() == result.unsafe_buffer_pointer(), "JAX → torch copied"


def test_overflowing_capacity_is_flagged_never_silent(rasterizer: JaxRasterizer) -> None:
    gaussians = rasterizer.prepare(as_jax(scene(24)), jax_cameras())
    render = jax.jit(rasterize_fixed, static_argnames="spec")
    out = render(gaussians.gaussians, jax_cameras(), gaussians.background, gaussians.means2d, gaussians.kept,
                 spec=RasterSpec(WIDTH, HEIGHT, max_blocks=2))
    assert bool(out.overflow) and int(out.needed_blocks) > 2
    assert bool(jnp.isnan(out.rgb).all()) and bool(jnp.isnan(out.depth).all())


def test_overflow_grows_the_capacity_and_renders_again(rasterizer: JaxRasterizer) -> None:
    far, near = scene(200, seed=3, depth=8.0), scene(200, seed=3, depth=1.0)  # near: far more cells covered
    cams = jax_cameras()
    rasterizer(as_jax(far), cams, WIDTH, HEIGHT)
    reruns = rasterizer.stats.reruns
    out = rasterizer(as_jax(near), cams, WIDTH, HEIGHT)
    assert rasterizer.stats.reruns == reruns + 1
    assert not bool(out.overflow) and bool(jnp.isfinite(out.rgb).all())
    expected = reference(as_torch(near, torch.float64), torch_cameras(torch.float64))
    np.testing.assert_allclose(np.asarray(out.rgb), expected.rgb.detach().numpy(), atol=1e-4)


def test_inside_jit_explains_what_to_use(rasterizer: JaxRasterizer) -> None:
    with pytest.raises(ValueError, match="rasterize_fixed"):
        jax.jit(lambda g: rasterizer(g, jax_cameras(), WIDTH, HEIGHT).rgb)(as_jax(scene(8)))


def test_in_place_change_before_backward_is_rejected(renderer: JaxRenderer) -> None:
    """JAX reads the parameters' memory (shared through DLPack) until backward: an in-place update in
    between must fail loudly, as in torch autograd, not give a silently wrong gradient."""
    gaussians = as_torch(scene(200, seed=200), torch.float32)
    out = renderer.render(gaussians, torch_cameras(torch.float32))
    with torch.no_grad():
        gaussians.means.add_(0.01)
    with pytest.raises(RuntimeError, match="inplace"):
        out.rgb.sum().backward()
