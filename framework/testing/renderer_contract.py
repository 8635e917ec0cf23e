"""The renderer contract suite: docs/rendering.md as tests, written once for every renderer backend.

Each backend is reached by its registered name and compared with ``torch-reference`` run in float64 (the
oracle), or with closed-form values where the page fixes one (pixel centres, radii, α cap, early stop, tie
order). To run it against a renderer, subclass :class:`RendererContract` in a test module::

    from mmcsplat.testing.renderer_contract import RendererContract

    class TestMyRenderer(RendererContract):
        renderers = ["my-renderer"]  # registered names; None (the default) = every registered renderer

Unavailable renderers are skipped with their registry reason. A backend that wraps a rasterizer with
documented deviations from the page declares them in ``tolerances`` (see :class:`Tolerance`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence

import attrs
import pytest
import torch

from mmcsplat.configuration.registry import default_registry
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.render_contract import (
    ALPHA_MAX,
    ALPHA_MIN,
    LOW_PASS,
    SIGMA_EXTENT,
    TILE_SIZE,
    Gaussians,
    RenderCameras,
    RenderInputError,
    RenderOutput,
    viewmat_looking_at,
)

REFERENCE = "torch-reference"
FIELDS = tuple(field.name for field in attrs.fields(Gaussians))
IMAGES = ("rgb", "features", "depth", "alpha")


@attrs.frozen
class Tolerance:
    """How closely a backend must follow the reference.

    forward_atol: absolute error allowed per output value (float32 against the float64 reference).
    gradient_rtol: allowed ‖g − g_ref‖ / ‖g_ref‖ per parameter tensor.
    outlier_fraction: fraction of pixels allowed beyond ``forward_atol``. A float32 α within rounding of
    the 1/255 skip, or a T′ within rounding of the 1e-4 stop, legitimately flips at such a pixel (the
    image jumps by up to ~1/255 there); 1 in 2000 pixels covers that and still catches a wrong formula.
    radius_mismatch_fraction: fraction of Gaussians whose radius may differ by 1 (ceil of 3·sqrt(λ₁) at
    an integer, in float32).
    deviations: names of exact-value checks the backend documents it does not meet (with ``reason``):
    ``alpha_cap``, ``early_termination`` and ``jacobian_clamp`` (the closed form of a Gaussian beyond the
    clamp's limits) are skipped; ``tile_cover`` (tiles assigned by the backend's
    own boxes) leaves out of the closed-form α check the fringe pixels where both α values are below
    :data:`FRINGE_ALPHA`; ``transmittance_from_alpha`` (a backward pass that recovers transmittance as
    1 − α of the pixel, which float32 holds to ~1e-7 absolute, so to ~1e-3 relative behind a nearly
    opaque pixel) checks the early-termination gradients to a relative 1e-3 instead of 1e-5 absolute.
    """

    forward_atol: float = 1e-4
    gradient_rtol: float = 1e-3
    outlier_fraction: float = 1 / 2000
    radius_mismatch_fraction: float = 1e-4
    deviations: frozenset[str] = frozenset()
    reason: str = ""


#: Beyond the page's 3σ radius a Gaussian's α is at most o·e^(−4.5) < 0.0112: a backend that assigns
#: tiles by other boxes (``tile_cover``) may add or drop such pixels, never brighter ones.
FRINGE_ALPHA = 3 / 255


# --------------------------------------------------------------------------------------------- scenes


@attrs.frozen
class SceneSpec:
    """A seeded infant-like scene: ``n`` Gaussians (a 0.5 m subject at the origin, as bench scene B) seen
    by cameras at ``cameras`` positions of a ring (1.5 m out, 1 m up, 45° apart, offset 10°)."""

    n: int
    width: int = 64
    height: int = 48
    seed: int = 0
    cameras: tuple[int, ...] = (0,)


def ring_cameras(width: int, height: int, positions: Sequence[int]) -> RenderCameras:
    """Cameras looking at the origin; fx ≠ fy and an off-centre principal point, so that a swapped or
    misplaced intrinsic shows."""
    fx = 2.0 * width
    K = torch.tensor([[fx, 0.0, 0.52 * width], [0.0, 1.05 * fx, 0.485 * height], [0.0, 0.0, 1.0]])
    angles = [math.radians(45 * k + 10) for k in positions]
    viewmats = torch.stack([viewmat_looking_at((1.5 * math.cos(a), 1.5 * math.sin(a), 1.0)) for a in angles])
    return RenderCameras(K.expand(len(angles), 3, 3).clone(), viewmats, width, height)


@functools.cache
def infant_scene(spec: SceneSpec) -> tuple[Gaussians, RenderCameras]:
    """float32 Gaussians (with F = 3 features) and cameras of ``spec``; Gaussians shrink as n grows
    (0.8 cm at n = 1000, as in bench scene B)."""
    g = torch.Generator().manual_seed(spec.seed)
    n = spec.n
    means = torch.randn(n, 3, generator=g) * torch.tensor([0.12, 0.06, 0.05])
    quats = torch.randn(n, 4, generator=g)
    log_scales = math.log(0.08 / n ** (1 / 3)) + 0.3 * torch.randn(n, 3, generator=g)
    opacity_logits = torch.logit(torch.rand(n, generator=g) * 0.8 + 0.1)
    colors = torch.rand(n, 3, generator=g)
    features = torch.rand(n, 3, generator=g)
    return Gaussians(means, quats, log_scales, opacity_logits, colors, features), ring_cameras(spec.width, spec.height, spec.cameras)


def gaussians_from(
    means: Sequence[Sequence[float]],
    scales: Sequence[Sequence[float]],
    opacities: Sequence[float],
    colors: Sequence[Sequence[float]] | None = None,
    quats: Sequence[Sequence[float]] | None = None,
) -> Gaussians:
    """float32 Gaussians from plain values (linear scales and opacities; identity rotations and grey by
    default; features = colours reversed, F = 3)."""
    means_t = torch.tensor(means, dtype=torch.float32).reshape(-1, 3)
    n = means_t.shape[0]
    colors_t = torch.full((n, 3), 0.5) if colors is None else torch.tensor(colors, dtype=torch.float32)
    quats_t = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1) if quats is None else torch.tensor(quats, dtype=torch.float32)
    log_scales = torch.log(torch.tensor(scales, dtype=torch.float32).reshape(n, 3))
    logits = torch.logit(torch.tensor(opacities, dtype=torch.float64)).float()
    return Gaussians(means_t, quats_t, log_scales, logits, colors_t, colors_t.flip(-1).contiguous())


def front_camera(width: int = 40, height: int = 30, f: float = 50.0, cx: float = 20.0, cy: float = 10.0) -> RenderCameras:
    """One camera at the origin looking down +z (identity world-to-camera)."""
    K = torch.tensor([[[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]])
    return RenderCameras(K, torch.eye(4)[None], width, height)


def with_grad(gaussians: Gaussians, dtype: torch.dtype = torch.float32) -> Gaussians:
    """Fresh leaf copies in ``dtype``, all requiring grad."""
    return Gaussians(*(getattr(gaussians, f).detach().to(dtype).clone().requires_grad_() for f in FIELDS))


def cameras_as(cameras: RenderCameras, dtype: torch.dtype) -> RenderCameras:
    """The cameras with K and viewmats in ``dtype``."""
    return RenderCameras(cameras.K.to(dtype), cameras.viewmats.to(dtype), cameras.width, cameras.height)


# ---------------------------------------------------------------------------------------- reference


def renderer_for(name: str) -> Renderer:
    """The registered renderer ``name`` (one instance per process, so compiled kernels are reused); skips
    the test with the registry's reason when the renderer is unavailable here."""
    reason = default_registry().get("renderer", name).unavailable_reason()
    if reason:
        pytest.skip(f"renderer {name!r} is unavailable here: {reason}")
    return _create(name)


@functools.cache
def _create(name: str) -> Renderer:
    return default_registry().create("renderer", name)


def reference_render(gaussians: Gaussians, cameras: RenderCameras, background: torch.Tensor | None = None) -> RenderOutput:
    """The oracle: torch-reference in float64, no gradients."""
    with torch.no_grad():
        return renderer_for(REFERENCE).render(
            with_grad(gaussians, torch.float64), cameras_as(cameras, torch.float64),
            None if background is None else background.double(),
        )


def loss_of(out: RenderOutput, seed: int = 1) -> torch.Tensor:
    """A fixed random linear loss touching colour, features, depth and alpha."""
    g = torch.Generator().manual_seed(seed)
    total = 0
    for name, scale in zip(IMAGES, (1.0, 1.0, 0.3, 1.0)):
        image = getattr(out, name)
        weights = torch.rand(image.shape, generator=g, dtype=torch.float64) * scale
        total = total + (image * weights.to(device=image.device, dtype=image.dtype)).sum()
    return total


def gradients(renderer: Renderer, gaussians: Gaussians, cameras: RenderCameras, dtype: torch.dtype = torch.float32) -> list[torch.Tensor]:
    """d loss_of / d (each Gaussian parameter, then means2d), on the CPU in float64."""
    leaves = with_grad(gaussians, dtype)
    out = renderer.render(leaves, cameras_as(cameras, dtype))
    params = [getattr(leaves, f) for f in FIELDS] + [out.means2d]
    grads = torch.autograd.grad(loss_of(out), params, allow_unused=True, materialize_grads=True)
    return [g.detach().cpu().double() for g in grads]


@functools.cache
def reference_gradients(spec: SceneSpec) -> list[torch.Tensor]:
    """The oracle's float64 gradients on a seeded scene."""
    return gradients(renderer_for(REFERENCE), *infant_scene(spec), dtype=torch.float64)


@functools.cache
def reference_scene_render(spec: SceneSpec) -> RenderOutput:
    """The oracle's float64 render of a seeded scene (cached across backends)."""
    return reference_render(*infant_scene(spec))


# ------------------------------------------------------------------------------------------ checks


def assert_images_close(actual: RenderOutput, expected: RenderOutput, tolerance: Tolerance, atol: float | None = None) -> None:
    """Every image of ``actual`` within ``atol`` (default ``tolerance.forward_atol``) of ``expected``,
    except at most ``tolerance.outlier_fraction`` of the pixels; never NaN."""
    atol = tolerance.forward_atol if atol is None else atol
    for name in IMAGES:
        a, e = getattr(actual, name).detach().cpu().double(), getattr(expected, name).detach().cpu().double()
        assert a.shape == e.shape, f"{name}: shape {tuple(a.shape)}, expected {tuple(e.shape)}"
        assert torch.isfinite(a).all(), f"{name} has non-finite values"
        if a.numel() == 0:
            continue
        diff = (a - e).abs()
        per_pixel = diff.reshape(*diff.shape[:3], -1).amax(-1)  # [C, H, W]
        bad = per_pixel > atol
        allowed = int(tolerance.outlier_fraction * per_pixel.numel())
        if int(bad.sum()) > allowed:
            c, v, u = (int(i) for i in torch.nonzero(per_pixel == per_pixel.max())[0])
            raise AssertionError(
                f"{name}: {int(bad.sum())} of {per_pixel.numel()} pixels differ from torch-reference by more than "
                f"{atol:g} ({allowed} allowed); worst {float(per_pixel.max()):.3g} at camera {c}, pixel (u={u}, v={v}): "
                f"{a[c, v, u].tolist()} vs {e[c, v, u].tolist()}"
            )


def assert_radii_match(actual: torch.Tensor, expected: torch.Tensor, tolerance: Tolerance) -> None:
    """Integer radii equal to the reference's, but for a ``radius_mismatch_fraction`` off by one."""
    a, e = actual.cpu().long(), expected.cpu().long()
    assert a.shape == e.shape, f"radii: shape {tuple(a.shape)}, expected {tuple(e.shape)}"
    differ = a != e
    allowed = int(tolerance.radius_mismatch_fraction * a.shape[-1])
    assert int(differ.sum()) <= allowed and bool(((a - e).abs() <= 1).all()), (
        f"radii differ from torch-reference for {int(differ.sum())} Gaussians ({allowed} allowed, each by at most 1): "
        f"indices {torch.nonzero(differ)[:5].tolist()}, {a[differ][:5].tolist()} vs {e[differ][:5].tolist()}"
    )


def assert_gradients_close(actual: Sequence[torch.Tensor], expected: Sequence[torch.Tensor], rtol: float) -> None:
    """Per parameter, ‖g − g_ref‖ / max(‖g_ref‖, 1e-12) ≤ ``rtol``; every gradient finite."""
    for name, a, e in zip((*FIELDS, "means2d"), actual, expected):
        assert a.shape == e.shape, f"grad {name}: shape {tuple(a.shape)}, expected {tuple(e.shape)}"
        assert torch.isfinite(a).all(), f"grad {name} has non-finite values"
        error = float((a - e).norm() / e.norm().clamp_min(1e-12))
        assert error <= rtol, f"grad {name}: relative error {error:.3g} against torch-reference (allowed {rtol:g})"


def clamp_limits(intrinsics: Sequence[float], width: int, height: int) -> list[tuple[float, float]]:
    """The Jacobian clamp's (negative, positive) limits of x/z and y/z: 1.3 × the field of view's half-widths."""
    fx, fy, cx, cy = intrinsics
    return [(cx / fx + 0.3 * width / (2 * fx), (width - cx) / fx + 0.3 * width / (2 * fx)),
            (cy / fy + 0.3 * height / (2 * fy), (height - cy) / fy + 0.3 * height / (2 * fy))]


def closed_form_single(
    mean: Sequence[float], scale: float, opacity: float, intrinsics: Sequence[float], width: int, height: int
) -> tuple[torch.Tensor, int]:
    """docs/rendering.md for one isotropic Gaussian seen by a camera at the origin (identity
    world-to-camera), in plain float64 Python: its α image [H, W] and its radius."""
    x, y, z = mean
    fx, fy, cx, cy = intrinsics
    lim = clamp_limits(intrinsics, width, height)
    tx = z * min(max(x / z, -lim[0][0]), lim[0][1])
    ty = z * min(max(y / z, -lim[1][0]), lim[1][1])
    j = [[fx / z, 0.0, -fx * tx / z**2], [0.0, fy / z, -fy * ty / z**2]]
    cov = [[scale**2 * sum(j[r][k] * j[s][k] for k in range(3)) + (LOW_PASS if r == s else 0.0) for s in range(2)] for r in range(2)]
    a, b, c = cov[0][0], cov[0][1], cov[1][1]
    det = a * c - b * b
    mid = (a + c) / 2
    radius = math.ceil(SIGMA_EXTENT * math.sqrt(mid + math.sqrt(max(0.1, mid * mid - det))))
    mx, my = fx * x / z + cx, fy * y / z + cy
    tiles_x, tiles_y = -(-width // TILE_SIZE), -(-height // TILE_SIZE)
    x0, x1 = (min(max(math.floor(t / TILE_SIZE), 0), tiles_x) for t in (mx - radius, mx + radius + TILE_SIZE - 1))
    y0, y1 = (min(max(math.floor(t / TILE_SIZE), 0), tiles_y) for t in (my - radius, my + radius + TILE_SIZE - 1))
    alpha = torch.zeros(height, width, dtype=torch.float64)
    for v in range(height):
        for u in range(width):
            if not (x0 <= u // TILE_SIZE < x1 and y0 <= v // TILE_SIZE < y1):
                continue
            dx, dy = u - mx, v - my
            power = -0.5 * (c * dx * dx + a * dy * dy) / det + b * dx * dy / det
            value = min(ALPHA_MAX, opacity * math.exp(power))
            alpha[v, u] = value if power <= 0 and value >= ALPHA_MIN else 0.0
    return alpha, radius if x1 > x0 and y1 > y0 else 0


def peak(tensor: torch.Tensor) -> float:
    """max |tensor|, detached."""
    return float(tensor.detach().abs().max())


def pixel(out: RenderOutput, name: str, u: int, v: int, camera: int = 0) -> torch.Tensor:
    """One pixel of one output, as float64 on the CPU."""
    return getattr(out, name)[camera, v, u].detach().cpu().double()


# ------------------------------------------------------------------------------------------- suite


class RendererContract:
    """The contract tests, parametrized over ``renderers`` (registered names; None = all registered)."""

    renderers: Sequence[str] | None = None
    #: Per-renderer tolerances; a renderer not listed gets the default :class:`Tolerance`.
    tolerances: Mapping[str, Tolerance] = {}

    def pytest_generate_tests(self, metafunc: pytest.Metafunc) -> None:
        """Parametrize every test taking ``renderer_name`` over the renderers under test."""
        if "renderer_name" in metafunc.fixturenames:
            names = list(self.renderers) if self.renderers is not None else default_registry().names("renderer")
            metafunc.parametrize("renderer_name", names)

    @pytest.fixture
    def renderer(self, renderer_name: str) -> Renderer:
        return renderer_for(renderer_name)

    @pytest.fixture
    def tolerance(self, renderer_name: str) -> Tolerance:
        return self.tolerances.get(renderer_name, Tolerance())

    @staticmethod
    def skip_deviation(tolerance: Tolerance, check: str) -> None:
        if check in tolerance.deviations:
            pytest.skip(f"documented deviation from docs/rendering.md ({check}): {tolerance.reason}")

    # ------------------------------------------------------------------ agreement with the reference

    @pytest.mark.parametrize("n", [1, 10, 1000, pytest.param(10000, marks=pytest.mark.slow)])
    def test_forward_matches_reference(self, renderer: Renderer, tolerance: Tolerance, n: int) -> None:
        spec = SceneSpec(n)
        gaussians, cameras = infant_scene(spec)
        out = renderer.render(gaussians, cameras)
        c, h, w = cameras.count, cameras.height, cameras.width
        shapes = {"rgb": (c, h, w, 3), "features": (c, h, w, 3), "depth": (c, h, w), "alpha": (c, h, w),
                  "radii": (c, n), "means2d": (c, n, 2)}
        for name, shape in shapes.items():
            assert tuple(getattr(out, name).shape) == shape, f"{name}: shape {tuple(getattr(out, name).shape)}, expected {shape}"
        for name in IMAGES:
            assert getattr(out, name).dtype == torch.float32, f"{name}: dtype {getattr(out, name).dtype} for float32 input"
        assert not out.radii.is_floating_point(), f"radii must be integers, got {out.radii.dtype}"
        expected = reference_scene_render(spec)
        assert_images_close(out, expected, tolerance)
        assert_radii_match(out.radii, expected.radii, tolerance)
        assert bool(out.alpha.max() > 0.5), "the scene must be in view"

    @pytest.mark.parametrize("n", [1, 10, 1000, pytest.param(10000, marks=pytest.mark.slow)])
    def test_gradients_match_reference(self, renderer: Renderer, tolerance: Tolerance, n: int) -> None:
        spec = SceneSpec(n)
        grads = gradients(renderer, *infant_scene(spec))
        expected = reference_gradients(spec)
        assert all(bool(e.abs().sum() > 0) for e in expected), "every parameter must receive a gradient"
        assert_gradients_close(grads, expected, tolerance.gradient_rtol)

    def test_means2d_grad_after_backward(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """Densification reads ``out.means2d.grad`` after ``loss.backward()``."""
        spec = SceneSpec(10)
        leaves = with_grad(infant_scene(spec)[0])
        out = renderer.render(leaves, infant_scene(spec)[1])
        loss_of(out).backward()
        assert out.means2d.grad is not None, "RenderOutput.means2d.grad is None after backward"
        assert_gradients_close([out.means2d.grad.cpu().double()], [reference_gradients(spec)[-1]], tolerance.gradient_rtol)

    def test_camera_batch_equals_single_cameras(self, renderer: Renderer, tolerance: Tolerance) -> None:
        gaussians, cameras = infant_scene(SceneSpec(300, 40, 24, seed=3, cameras=(0, 3, 5)))
        batch = renderer.render(gaussians, cameras)
        for index in range(cameras.count):
            alone = renderer.render(gaussians, cameras.select([index]))
            one = RenderOutput(*(getattr(batch, f)[index : index + 1] for f in (*IMAGES, "radii", "means2d")))
            assert_images_close(one, alone, tolerance, atol=1e-5)
            assert torch.equal(one.radii.cpu(), alone.radii.cpu()), f"camera {index}: radii differ between batch and single"

    @pytest.mark.parametrize("size", [(37, 23), (16, 48), (50, 17), (1, 1)])
    def test_image_sizes(self, renderer: Renderer, tolerance: Tolerance, size: tuple[int, int]) -> None:
        """Non-square images, W or H not a multiple of 16 (partial edge tiles), a single pixel."""
        gaussians, cameras = infant_scene(SceneSpec(200, *size, seed=4))
        out = renderer.render(gaussians, cameras)
        expected = reference_render(gaussians, cameras)
        assert_images_close(out, expected, tolerance)
        assert_radii_match(out.radii, expected.radii, tolerance)

    @pytest.mark.parametrize("background", [[0.2, 0.5, 0.9], [[0.2, 0.5, 0.9], [1.0, 0.0, 0.3]]])
    def test_background(self, renderer: Renderer, tolerance: Tolerance, background: list) -> None:
        """rgb = colour + T·background ([3] or per camera [C, 3]); features, depth, alpha unaffected."""
        gaussians, cameras = infant_scene(SceneSpec(100, 40, 24, seed=5, cameras=(1, 6)))
        bg = torch.tensor(background)
        out = renderer.render(gaussians, cameras, bg)
        black = renderer.render(gaussians, cameras)
        per_camera = bg.expand(cameras.count, 3).cpu().double()
        composited = black.rgb.cpu().double() + (1 - black.alpha.cpu().double())[..., None] * per_camera[:, None, None, :]
        assert torch.allclose(out.rgb.cpu().double(), composited, atol=1e-5), "rgb ≠ colour + (1 − alpha)·background"
        for name in ("features", "depth", "alpha"):
            assert torch.allclose(getattr(out, name).cpu(), getattr(black, name).cpu(), atol=1e-6), f"background changed {name}"
        assert_images_close(out, reference_render(gaussians, cameras, bg), tolerance)

    # ------------------------------------------------------------------ closed-form conventions

    def test_pixel_centres_and_footprint(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """Pixel (u, v) is sampled at (u, v) (OpenCV); α = o·exp(−½ dᵀ Σ₂⁻¹ d), Σ₂ = (f·s/z)² + 0.3."""
        s, z, f, o = 0.02, 2.0, 50.0, 0.5
        var = (f * s / z) ** 2 + LOW_PASS
        for cx, u_peak in ((20.0, [20]), (20.5, [20, 21])):
            out = renderer.render(gaussians_from([[0, 0, z]], [[s, s, s]], [o]), front_camera(cx=cx))
            for u in (18, 19, 20, 21, 22):
                for v in (9, 10, 11):
                    expected = o * math.exp(-0.5 * ((u - cx) ** 2 + (v - 10) ** 2) / var)
                    expected = expected if expected >= 1 / 255 else 0.0
                    got = float(pixel(out, "alpha", u, v))
                    assert got == pytest.approx(expected, abs=2e-6), f"cx={cx}: alpha at pixel ({u}, {v}) is {got}, expected {expected}"
            peak = [float(pixel(out, "alpha", u, 10)) for u in u_peak]
            assert peak[0] == pytest.approx(peak[-1], abs=1e-7)
            assert float(pixel(out, "depth", u_peak[0], 10)) == pytest.approx(z, abs=1e-5)
            assert pixel(out, "rgb", u_peak[0], 10).tolist() == pytest.approx([0.5 * peak[0]] * 3, abs=1e-6)

    @pytest.mark.parametrize(
        "mean, scale, opacity",
        [((0.1, 0.05, 2.0), 0.03, 0.7), ((-0.3, 0.2, 1.5), 0.05, 0.5),
         ((1.8, 0.1, 2.0), 0.3, 0.9), ((0.05, -1.6, 2.0), 0.5, 0.9)],
        ids=["off-axis", "off-axis-near", "right-clamped", "top-clamped"],
    )
    def test_single_gaussian_closed_form(self, renderer: Renderer, tolerance: Tolerance, mean: tuple, scale: float, opacity: float) -> None:
        """One isotropic Gaussian, every pixel's α and the radius against the page evaluated in plain
        Python: fx ≠ fy, an off-centre principal point, and the Jacobian clamp far off-screen."""
        fx, fy, cx, cy, width, height = 50.0, 60.0, 17.5, 8.5, 40, 30
        (x_neg, x_pos), (y_neg, y_pos) = clamp_limits((fx, fy, cx, cy), width, height)
        if not (-x_neg <= mean[0] / mean[2] <= x_pos and -y_neg <= mean[1] / mean[2] <= y_pos):
            self.skip_deviation(tolerance, "jacobian_clamp")
        K = torch.tensor([[[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]])
        out = renderer.render(gaussians_from([mean], [[scale] * 3], [opacity]), RenderCameras(K, torch.eye(4)[None], width, height))
        expected_alpha, expected_radius = closed_form_single(mean, scale, opacity, (fx, fy, cx, cy), width, height)
        assert int(out.radii[0, 0]) == expected_radius, f"radius {int(out.radii[0, 0])}, expected {expected_radius}"
        got = out.alpha[0].detach().cpu().double()
        error = (got - expected_alpha).abs()
        if "tile_cover" in tolerance.deviations:
            error[(got < FRINGE_ALPHA) & (expected_alpha < FRINGE_ALPHA)] = 0.0
        v, u = divmod(int(error.argmax()), width)
        assert float(error.max()) <= 1e-5, f"alpha at pixel ({u}, {v}) is {float(out.alpha[0, v, u])}, expected {float(expected_alpha[v, u])}"
        assert float(expected_alpha.max()) > 0.02, "the Gaussian must reach the image"

    def test_radii(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """r = ceil(3·sqrt(λ₁)), λ₁ = mid + sqrt(max(0.1, mid² − det)) of Σ₂ (an axis-aligned Gaussian here)."""
        scales = [[0.02, 0.02, 0.02], [0.2, 0.03, 0.02], [0.01, 0.4, 0.05], [1e-6, 1e-6, 1e-6]]
        out = renderer.render(gaussians_from([[0, 0, 2.0]] * 4, scales, [0.5] * 4), front_camera())
        for i, (sx, sy, _) in enumerate(scales):
            a, c = (50 * sx / 2) ** 2 + LOW_PASS, (50 * sy / 2) ** 2 + LOW_PASS
            mid = (a + c) / 2
            expected = math.ceil(SIGMA_EXTENT * math.sqrt(mid + math.sqrt(max(0.1, mid * mid - a * c))))
            assert int(out.radii[0, i]) == expected, f"Gaussian {i}: radius {int(out.radii[0, i])}, expected {expected}"
        assert out.visible.all()

    def test_tile_range_culls_gaussians_off_the_left_edge(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """x1 = floor((m_x + r + 15) / 16): a footprint reaching less than one pixel into the image covers
        no tile and is culled (radius 0); one reaching further is kept."""
        s = 0.02  # Σ₂ ≈ 0.55 px² → r = 3
        # m_x; the camera has f = 50, cx = 20, W = 40 (3 tiles: the last one reaches x = 47), z = 2
        xs = [-2.5, -1.5, 50.5, 51.5]
        out = renderer.render(gaussians_from([[(x - 20) * 2 / 50, 0, 2.0] for x in xs], [[s, s, s]] * 4, [0.5] * 4), front_camera())
        tiles_x = -(-40 // TILE_SIZE)
        for i, x in enumerate(xs):
            x0 = min(max(math.floor((x - 3) / TILE_SIZE), 0), tiles_x)
            x1 = min(max(math.floor((x + 3 + TILE_SIZE - 1) / TILE_SIZE), 0), tiles_x)
            assert int(out.radii[0, i]) == (3 if x1 > x0 else 0), f"Gaussian at m_x = {x}: radius {int(out.radii[0, i])}"

    def test_alpha_cap(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """α = min(0.99, o·exp(power)); the clamped α passes no gradient to the opacity."""
        self.skip_deviation(tolerance, "alpha_cap")
        gaussians = with_grad(gaussians_from([[0, 0, 2.0]], [[0.05, 0.05, 0.05]], [0.999], colors=[[0.2, 0.4, 0.8]]))
        out = renderer.render(gaussians, front_camera())
        assert float(pixel(out, "alpha", 20, 10)) == pytest.approx(ALPHA_MAX, abs=1e-6)
        assert pixel(out, "rgb", 20, 10).tolist() == pytest.approx([0.99 * 0.2, 0.99 * 0.4, 0.99 * 0.8], abs=1e-6)
        (grad,) = torch.autograd.grad(out.alpha[0, 10, 20], [gaussians.opacity_logits])
        assert float(grad.abs().max()) == 0.0, "a clamped alpha must pass no gradient"

    def test_early_termination(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """Four stacked Gaussians with α = 0.95 at the centre pixel: T goes 0.05, 0.0025, 1.25e-4; the fourth
        would bring it below 1e-4, so it and everything behind it are ignored there."""
        self.skip_deviation(tolerance, "early_termination")
        colors = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]]
        zs = [2.0, 2.2, 2.4, 2.6]
        gaussians = with_grad(gaussians_from([[0, 0, z] for z in zs], [[0.05, 0.05, 0.05]] * 4, [0.95] * 4, colors=colors))
        out = renderer.render(gaussians, front_camera())
        weights = [0.95, 0.95 * 0.05, 0.95 * 0.0025]
        assert pixel(out, "rgb", 20, 10).tolist() == pytest.approx(weights, abs=1e-5)
        assert float(pixel(out, "alpha", 20, 10)) == pytest.approx(1 - 1.25e-4, abs=1e-6)
        depth = sum(w * z for w, z in zip(weights, zs)) / sum(weights)
        assert float(pixel(out, "depth", 20, 10)) == pytest.approx(depth, abs=1e-5)
        (grad,) = torch.autograd.grad(out.rgb[0, 10, 20].sum(), [gaussians.colors])
        rel = 1e-3 if "transmittance_from_alpha" in tolerance.deviations else None
        assert grad[:, 0].tolist() == pytest.approx(weights + [0.0], rel=rel, abs=1e-5), f"colour gradients {grad[:, 0].tolist()}"

    def test_equal_depths_composite_in_index_order(self, renderer: Renderer, tolerance: Tolerance) -> None:
        colors = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
        scales = [[0.03, 0.03, 0.03], [0.05, 0.02, 0.02], [0.02, 0.06, 0.02]]
        for order in ([0, 1, 2], [2, 0, 1]):
            gaussians = gaussians_from([[0, 0, 2.0]] * 3, [scales[i] for i in order], [0.6] * 3, colors=[colors[i] for i in order])
            out = renderer.render(gaussians, front_camera())
            expected = [0.0, 0.0, 0.0]
            for rank, i in enumerate(order):
                expected[i] = 0.6 * 0.4**rank  # colour i is the unit vector e_i
            assert pixel(out, "rgb", 20, 10).tolist() == pytest.approx(expected, abs=1e-5), f"index order {order}"
            assert_images_close(out, reference_render(gaussians, front_camera()), tolerance)

    def test_depth_is_expected_depth(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """depth = Σ wᵢ zᵢ / alpha where drawn, 0 where nothing was drawn."""
        zs, opacities = [1.5, 3.0], [0.5, 0.8]
        out = renderer.render(gaussians_from([[0, 0, z] for z in zs], [[0.02] * 3, [0.04] * 3], opacities), front_camera())
        w = [0.5, 0.8 * 0.5]
        assert float(pixel(out, "depth", 20, 10)) == pytest.approx((w[0] * zs[0] + w[1] * zs[1]) / sum(w), abs=1e-5)
        assert float(pixel(out, "alpha", 0, 29)) == 0.0 and float(pixel(out, "depth", 0, 29)) == 0.0

    # ------------------------------------------------------------------ edge cases

    def test_no_gaussians(self, renderer: Renderer, tolerance: Tolerance) -> None:
        empty = Gaussians(torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3), torch.zeros(0, 3))
        out = renderer.render(empty, front_camera(), torch.tensor([0.1, 0.2, 0.3]))
        assert tuple(out.radii.shape) == (1, 0) and tuple(out.means2d.shape) == (1, 0, 2)
        assert out.rgb.cpu().double().sub(torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)).abs().max() < 1e-7
        assert tuple(out.features.shape) == (1, 30, 40, 3) and peak(out.features) == 0.0
        assert peak(out.alpha) == 0.0 and peak(out.depth) == 0.0

    def test_all_behind_the_camera(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """Behind the camera, at z = 0 and nearer than the near plane: culled, background only, zero gradients."""
        zs = [-1.0, -0.3, 0.0, 0.005]
        gaussians = with_grad(gaussians_from([[0, 0, z] for z in zs], [[0.05] * 3] * 4, [0.9] * 4))
        out = renderer.render(gaussians, front_camera(), torch.tensor([0.3, 0.3, 0.3]))
        assert int(out.radii.abs().max()) == 0 and not out.visible.any()
        assert torch.allclose(out.rgb.cpu(), torch.full_like(out.rgb.cpu(), 0.3)) and peak(out.alpha) == 0.0
        loss = loss_of(out)
        if loss.requires_grad:
            params = [getattr(gaussians, f) for f in FIELDS] + [out.means2d]
            for grad in torch.autograd.grad(loss, params, allow_unused=True, materialize_grads=True):
                assert torch.isfinite(grad).all() and float(grad.abs().max()) == 0.0

    def test_partly_off_screen(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """Gaussians around and beyond the image border (the Jacobian clamp at 1.3× the field of view)."""
        g = torch.Generator().manual_seed(6)
        n = 60
        means = torch.cat([(torch.rand(n, 2, generator=g) * 2 - 1) * torch.tensor([1.4, 1.1]), torch.full((n, 1), 1.0)], 1)
        means = means * (1.5 + torch.rand(n, 1, generator=g))
        scales = torch.exp(math.log(0.25) + 0.5 * torch.randn(n, 3, generator=g))
        gaussians = Gaussians(means, torch.randn(n, 4, generator=g), torch.log(scales), torch.randn(n, generator=g),
                              torch.rand(n, 3, generator=g), torch.rand(n, 3, generator=g))
        cameras = front_camera(40, 30, f=30.0, cx=19.5, cy=15.0)
        out = renderer.render(gaussians, cameras)
        expected = reference_render(gaussians, cameras)
        assert_images_close(out, expected, tolerance)
        assert_radii_match(out.radii, expected.radii, tolerance)
        assert 0 < int(out.visible.sum()) < n, "the scene must mix visible and culled Gaussians"
        grads = gradients(renderer, gaussians, cameras)
        assert_gradients_close(grads, gradients(renderer_for(REFERENCE), gaussians, cameras, torch.float64), tolerance.gradient_rtol)

    def test_very_large_and_very_small_scales(self, renderer: Renderer, tolerance: Tolerance) -> None:
        scales = [[3.0, 3.0, 3.0], [5.0, 0.01, 0.5], [1e-6, 1e-6, 1e-6], [1e-7, 0.02, 1e-7], [0.03, 0.03, 0.03]]
        means = [[0.1, 0.0, 4.0], [-0.2, 0.1, 5.0], [0.05, 0.02, 2.0], [-0.1, -0.05, 2.5], [0.0, 0.1, 3.0]]
        quats = [[1, 0, 0, 0], [0.9, 0.3, -0.2, 0.1], [1, 0, 0, 0], [0.5, 0.5, 0.5, 0.5], [0.7, 0, 0.7, 0]]
        gaussians = gaussians_from(means, scales, [0.3, 0.4, 0.9, 0.8, 0.7], quats=quats)
        cameras = front_camera(48, 32, f=40.0, cx=24.0, cy=16.0)
        out = renderer.render(gaussians, cameras)
        expected = reference_render(gaussians, cameras)
        assert_images_close(out, expected, tolerance)
        assert_radii_match(out.radii, expected.radii, tolerance)
        assert int(out.radii.max()) > 48, "the large Gaussians must cover the image"
        grads = gradients(renderer, gaussians, cameras)
        assert_gradients_close(grads, gradients(renderer_for(REFERENCE), gaussians, cameras, torch.float64), tolerance.gradient_rtol)

    def test_zero_opacity(self, renderer: Renderer, tolerance: Tolerance) -> None:
        """Opacity logits of −30: nothing drawn (α < 1/255), yet the Gaussians are visible (radius > 0)."""
        gaussians = gaussians_from([[0, 0, 2.0], [0.1, 0, 2.5]], [[0.05] * 3] * 2, [0.5, 0.5])
        gaussians = attrs.evolve(gaussians, opacity_logits=torch.full((2,), -30.0))
        gaussians = with_grad(gaussians)
        out = renderer.render(gaussians, front_camera(), torch.tensor([0.0, 0.5, 1.0]))
        assert peak(out.alpha) == 0.0 and peak(out.depth) == 0.0
        assert torch.allclose(out.rgb[0].cpu(), torch.tensor([0.0, 0.5, 1.0]).expand(30, 40, 3))
        assert bool(out.visible.all())
        loss = loss_of(out)
        if loss.requires_grad:
            params = [getattr(gaussians, f) for f in FIELDS]
            assert all(torch.isfinite(g).all() for g in torch.autograd.grad(loss, params, allow_unused=True, materialize_grads=True))

    def test_no_grad_mode(self, renderer: Renderer, tolerance: Tolerance) -> None:
        gaussians, cameras = infant_scene(SceneSpec(10))
        with torch.no_grad():
            out = renderer.render(with_grad(gaussians), cameras)
        assert not out.rgb.requires_grad
        assert_images_close(out, reference_scene_render(SceneSpec(10)), tolerance)

    # ------------------------------------------------------------------ bad input

    @pytest.mark.parametrize("field", FIELDS)
    @pytest.mark.parametrize("value", [math.nan, math.inf])
    def test_non_finite_parameters_are_rejected(self, renderer: Renderer, field: str, value: float) -> None:
        gaussians, cameras = infant_scene(SceneSpec(10))
        tensor = getattr(gaussians, field).clone()
        tensor.view(-1)[3] = value
        with pytest.raises(RenderInputError, match=field):
            renderer.render(attrs.evolve(gaussians, **{field: tensor}), cameras)

    @pytest.mark.parametrize(
        "field, shape",
        [("means", (10, 2)), ("quats", (10, 3)), ("log_scales", (10,)), ("opacity_logits", (10, 1)), ("colors", (11, 3)),
         ("features", (10,)), ("features", (9, 3))],
    )
    def test_wrong_shapes_are_rejected(self, renderer: Renderer, field: str, shape: tuple[int, ...]) -> None:
        gaussians, cameras = infant_scene(SceneSpec(10))
        with pytest.raises(RenderInputError, match=field):
            renderer.render(attrs.evolve(gaussians, **{field: torch.zeros(shape)}), cameras)

    def test_zero_quaternion_is_rejected(self, renderer: Renderer) -> None:
        gaussians, cameras = infant_scene(SceneSpec(10))
        quats = gaussians.quats.clone()
        quats[2] = 0
        with pytest.raises(RenderInputError, match="quats"):
            renderer.render(attrs.evolve(gaussians, quats=quats), cameras)

    @pytest.mark.parametrize("problem", ["K inf", "viewmats nan", "zero focal", "K shape", "viewmats count", "background nan", "background shape"])
    def test_bad_cameras_and_background_are_rejected(self, renderer: Renderer, problem: str) -> None:
        gaussians, cameras = infant_scene(SceneSpec(10))
        K, viewmats, background = cameras.K.clone(), cameras.viewmats.clone(), torch.zeros(3)
        if problem == "K inf":
            K[0, 0, 2] = math.inf
        elif problem == "viewmats nan":
            viewmats[0, 1, 3] = math.nan
        elif problem == "zero focal":
            K[0, 1, 1] = 0.0
        elif problem == "K shape":
            K = K[0]
        elif problem == "viewmats count":
            viewmats = viewmats.expand(2, 4, 4)
        elif problem == "background nan":
            background[1] = math.nan
        else:
            background = torch.zeros(4)
        with pytest.raises(RenderInputError, match="K|viewmats|focal|background"):
            renderer.render(gaussians, RenderCameras(K, viewmats, cameras.width, cameras.height), background)
