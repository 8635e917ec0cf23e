"""`mmcsplat bench`: the benchmark scenes as ../shared/bench/README.md defines them and mmcsplat's own scene D
(a real capture's first-frame fit: its size and the many tiles each Gaussian covers), the interleaved timing
protocol, the report's verdicts on the speed-up targets, and the command end to end."""

import json
import math
import sys
import types

import torch

from mmcsplat import Registration, hookimpl
from mmcsplat.bench.benchmark import BenchReport, SceneResult, Timing, build_scene, run_benchmark, to_json, to_markdown
from mmcsplat.cli import main
from mmcsplat.configuration.registry import Registry, default_registry
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.render_contract import TILE_SIZE, RenderOutput


def test_scene_a_is_drawn_in_readme_order():
    scene = build_scene("A")
    g = torch.Generator().manual_seed(0)
    means = (torch.rand(2000, 3, generator=g) * 2 - 1) * torch.tensor([1.0, 0.75, 0.5])
    means[:, 2] += 3.0
    quats = torch.randn(2000, 4, generator=g)
    scales = torch.rand(2000, 3, generator=g) * 0.05 + 0.01
    assert torch.equal(scene.gaussians.means, means) and torch.equal(scene.gaussians.quats, quats)
    assert torch.allclose(torch.exp(scene.gaussians.log_scales), scales)
    opacities = torch.sigmoid(scene.gaussians.opacity_logits)
    assert float(opacities.min()) >= 0.1 - 1e-6 and float(opacities.max()) <= 0.9 + 1e-6
    f = 0.5 * 128 / math.tan(math.radians(30))
    assert torch.allclose(scene.cameras.K[0], torch.tensor([[f, 0, 64], [0, f, 48], [0, 0, 1.0]]))
    assert torch.equal(scene.cameras.viewmats[0], torch.eye(4))
    assert (scene.cameras.width, scene.cameras.height, scene.gaussians.features.shape) == (128, 96, (2000, 0))


def test_scenes_b_and_c_share_gaussians_and_look_at_the_origin():
    b, c = build_scene("B"), build_scene("C")
    assert torch.equal(b.gaussians.means, c.gaussians.means) and b.gaussians.count == 10000
    assert torch.allclose(b.cameras.K[0], torch.tensor([[217.5, 0, 128], [0, 217.5, 96], [0, 0, 1.0]]))
    assert c.cameras.count == 8 and torch.equal(c.cameras.viewmats[0], b.cameras.viewmats[0])
    for k, viewmat in enumerate(c.cameras.viewmats):
        rotation, translation = viewmat[:3, :3], viewmat[:3, 3]
        centre = -rotation.T @ translation
        theta = math.radians(45 * k)
        assert torch.allclose(centre, torch.tensor([1.5 * math.cos(theta), 1.5 * math.sin(theta), 1.0]), atol=1e-5)
        assert torch.allclose(rotation @ rotation.T, torch.eye(3), atol=1e-6)
        assert torch.allclose(rotation[2], -centre / centre.norm(), atol=1e-6)  # optical axis through the origin
        assert float(rotation[1, 2]) < 0  # image y points down in the world (z up)


def tiles_covered(scene) -> torch.Tensor:
    """[C, N] tiles each Gaussian touches in each camera, from the torch-cpu renderer's screen radii."""
    with torch.no_grad():
        radii = default_registry().create("renderer", "torch-cpu").render(scene.gaussians, scene.cameras).radii.float()
    return torch.where(radii > 0, (2 * radii / TILE_SIZE + 1) ** 2, 0)


def test_scene_d_is_a_real_capture_first_fit():
    d = build_scene("D")
    assert (d.gaussians.count, d.cameras.count, d.cameras.width, d.cameras.height) == (3000, 4, 272, 480)
    f = 1675 * 272 / 1088
    assert torch.allclose(d.cameras.K[0], torch.tensor([[f, 0, 136], [0, f, 240], [0, 0, 1.0]]))
    for viewmat in d.cameras.viewmats:
        centre = -viewmat[:3, :3].T @ viewmat[:3, 3]
        assert torch.allclose(centre[:2].norm(), torch.tensor(3.5)) and math.isclose(float(centre[2]), 1.0, abs_tol=1e-5)
    # the initializers' start: isotropic, opacity 0.1, inside a standing person's box
    assert torch.equal(d.gaussians.log_scales[:, 0], d.gaussians.log_scales[:, 2])
    assert torch.allclose(torch.sigmoid(d.gaussians.opacity_logits), torch.tensor(0.1))
    assert float(d.gaussians.means[:, 2].min()) >= 0.05 - 1e-6 and float(d.gaussians.means[:, 2].max()) <= 1.75 + 1e-6


def test_scene_d_gaussians_each_cover_many_tiles_unlike_scene_b():
    d, b = tiles_covered(build_scene("D")), tiles_covered(build_scene("B"))
    assert bool((d > 0).all())  # every Gaussian in every camera
    assert float(d.median()) >= 9 and float(b.median()) <= 4


class Stub(Renderer):
    """Records the order of calls; the image depends on every parameter so gradients exist."""

    def __init__(self, name, calls):
        self.name, self.calls = name, calls

    def render(self, gaussians, cameras, background=None):
        self.calls.append(self.name)
        total = sum(t.sum() for t in (gaussians.means, gaussians.quats, gaussians.log_scales,
                                      gaussians.opacity_logits, gaussians.colors)) * 0
        c, h, w = cameras.count, cameras.height, cameras.width
        rgb = (total + gaussians.colors.mean()).expand(c, h, w, 3)
        zeros = torch.zeros(c, h, w)
        return RenderOutput(rgb, zeros[..., None][..., :0], zeros, zeros, torch.ones(c, gaussians.count, dtype=torch.int32),
                            torch.zeros(c, gaussians.count, 2))


def test_runs_are_interleaved_and_timed():
    calls = []
    renderers = {name: Stub(name, calls) for name in ("torch-reference", "torch-cpu", "jax")}
    report = run_benchmark(["B"], renderers, repeats=3, profile_missed=False)
    # warm-ups, then rounds whose order rotates so no backend always runs first
    assert calls[:3] == ["torch-reference", "torch-cpu", "jax"]
    assert calls[3:] == ["torch-reference", "torch-cpu", "jax", "torch-cpu", "jax", "torch-reference",
                         "jax", "torch-reference", "torch-cpu"]
    (result,) = report.results
    assert [len(t.runs_s) for t in result.timings] == [3, 3, 3]
    assert result.speedups["torch-reference"] == 1.0 and set(result.speedups) == set(renderers)
    assert report.environment["threads"]["torch"] == torch.get_num_threads()
    assert "torch" in report.environment["versions"]


def test_report_flags_targets():
    def timing(name, scene, median):
        return Timing(name, scene, 2.0, (median,) * 7, 100.0, None)

    report = BenchReport(
        results=(
            SceneResult("B", "B — infant-10k", (timing("torch-reference", "B", 1.0), timing("torch-cpu", "B", 0.05),
                                                 timing("jax", "B", 0.8)), {"torch-reference": 1.0, "torch-cpu": 20.0, "jax": 1.25}),
            SceneResult("C", "C — ring8", (timing("torch-cpu", "C", 0.5),), {}),
        ),
        environment={"date": "2026-01-01T00:00:00+00:00", "machine": {"cpu": "cpu", "memory_gib": 8, "platform": "linux"},
                     "threads": {"torch": 2}, "versions": {"torch": "2.13.0"}},
        repeats=7,
        profiles={"jax on scene B": "   10 calls  jit"},
    )
    markdown = to_markdown(report)
    assert "| torch-cpu | 2.000 | 0.050 | 0.050–0.050 | 100 | 20.00× | ≥ 10×: **met** |" in markdown
    assert "| jax | 2.000 | 0.800 | 0.800–0.800 | 100 | 1.25× | ≥ 2×: **not met** |" in markdown
    assert "- jax on scene B: target ≥ 2×, measured 1.25×." in markdown
    assert "torch-cpu on scene C: target ≥ 10×, measured not measured" in markdown
    assert "### Profile of one run: jax on scene B" in markdown and "10 calls  jit" in markdown
    data = to_json(report)
    assert {(m["backend"], m["scene"]) for m in data["missed_targets"]} == {("jax", "B"), ("torch-cpu", "C")}
    assert data["results"][0]["timings"][1]["median_s"] == 0.05


def test_bench_command_writes_the_report(tmp_path, capsys, monkeypatch):
    """End to end through the registry, with a stub backend registered as a plugin would be."""
    plugin = types.ModuleType("bench_stub_plugin")
    plugin.StubRenderer = lambda: Stub("stub", [])
    plugin.mmcsplat_renderers = hookimpl(lambda: [Registration("stub", "bench_stub_plugin:StubRenderer")])
    monkeypatch.setitem(sys.modules, "bench_stub_plugin", plugin)
    registry = Registry(plugin_modules=[("bench-stub", "tests", plugin)])
    monkeypatch.setattr("mmcsplat.cli.bench.default_registry", lambda: registry)
    path = tmp_path / "docs" / "performance.md"
    assert main(["bench", "--scene", "A,C", "--backend", "stub", "--repeats", "2", "--json", "--write", str(path)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [r["scene"] for r in data["results"]] == ["A", "C"]
    (timing,) = data["results"][0]["timings"]
    assert timing["backend"] == "stub" and len(timing["runs_s"]) == 2 and timing["warmup_s"] > 0
    text = path.read_text()
    assert "## Scene A — random-2k (N = 2000, 128×96, 1 camera)" in text
    assert "## Scene C — infant-10k-ring8 (N = 10000, 256×192, 8 cameras)" in text
    assert main(["bench", "--backend", "no-such-renderer", "--repeats", "1"]) == 2
    assert "no-such-renderer" in capsys.readouterr().err
