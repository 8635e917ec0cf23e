"""Renderer benchmark: the scenes of ../shared/bench/README.md (A, B, C), built exactly as written there,
mmcsplat's own scene D (a real capture's first-frame fit at its start, :func:`build_scene`), and the timing
protocol of ``mmcsplat bench`` (warm-up reported apart, interleaved timed runs, peak memory).

Backends are reached through the registry only; ``torch-reference`` is the baseline of the speed-ups.
"""

from __future__ import annotations

import cProfile
import datetime
import importlib.metadata
import io
import math
import os
import platform
import pstats
import re
import statistics
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import torch

from mmcsplat.plugin_api.errors import InputError
from mmcsplat.plugin_api.interfaces import Renderer
from mmcsplat.plugin_api.render_contract import Gaussians, RenderCameras, viewmat_looking_at
from mmcsplat.storage.memory import release_freed_memory

BASELINE = "torch-reference"
SCENES = {"A": "random-2k", "B": "infant-10k", "C": "infant-10k-ring8", "D": "first-fit-4cam"}
OWN_SCENES = ("D",)  # mmcsplat's own, not in ../shared/bench/README.md
#: Required speed-up over torch-reference (median of paired run ratios), by (backend, scene).
TARGETS = {("torch-cpu", "B"): 10.0, ("torch-cpu", "C"): 10.0, ("jax", "B"): 2.0}
#: Distributions whose versions a report records (those installed).
VERSIONED = ("mmcsplat", "torch", "numpy", "numba", "jax", "jaxlib", "gsplat")


@attrs.frozen(eq=False)
class BenchScene:
    """A benchmark scene: its letter, its name in the README, float32 CPU Gaussians and cameras."""

    key: str
    name: str
    gaussians: Gaussians
    cameras: RenderCameras

    def describe(self) -> str:
        """"B — infant-10k (N = 10000, 256×192, 1 camera)"; mmcsplat's own scenes say so."""
        c = self.cameras.count
        own = ", mmcsplat's own" if self.key in OWN_SCENES else ""
        return (f"{self.key} — {self.name}{own} (N = {self.gaussians.count}, {self.cameras.width}×{self.cameras.height}, "
                f"{c} camera{'s' if c > 1 else ''})")


def _intrinsics(f: float, width: int, height: int) -> torch.Tensor:
    return torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def build_scene(key: str) -> BenchScene:
    """Scene ``key`` drawn from ``torch.Generator().manual_seed(0)``: A, B and C in the README's order, D
    as :func:`first_fit_scene` draws it."""
    if key not in SCENES:
        raise InputError(f"unknown benchmark scene {key!r}; scenes are {', '.join(SCENES)}")
    g = torch.Generator().manual_seed(0)
    if key == "D":
        return first_fit_scene(g)
    if key == "A":
        n, width, height = 2000, 128, 96
        means = (torch.rand(n, 3, generator=g) * 2 - 1) * torch.tensor([1.0, 0.75, 0.5])
        means[:, 2] += 3.0
        quats = torch.randn(n, 4, generator=g)
        scales = torch.rand(n, 3, generator=g) * 0.05 + 0.01
        opacities = torch.rand(n, generator=g) * 0.8 + 0.1
        colors = torch.rand(n, 3, generator=g)
        f = 0.5 * width / math.tan(math.radians(30))
        viewmats = torch.eye(4)[None]
    else:
        n, width, height = 10000, 256, 192
        means = torch.randn(n, 3, generator=g) * torch.tensor([0.12, 0.06, 0.05])
        quats = torch.randn(n, 4, generator=g)
        scales = torch.exp(math.log(0.008) + 0.3 * torch.randn(n, 3, generator=g))
        opacities = torch.rand(n, generator=g) * 0.8 + 0.1
        colors = torch.rand(n, 3, generator=g)
        f = 1740 * 256 / 2048
        angles = [0.0] if key == "B" else [math.radians(45 * k) for k in range(8)]
        viewmats = torch.stack([viewmat_looking_at((1.5 * math.cos(a), 1.5 * math.sin(a), 1.0)) for a in angles])
    K = _intrinsics(f, width, height).expand(len(viewmats), 3, 3).clone()
    return BenchScene(key, SCENES[key], Gaussians.from_linear(means, quats, scales, opacities, colors),
                      RenderCameras(K, viewmats, width, height))


def first_fit_scene(g: torch.Generator) -> BenchScene:
    """Scene D, "first-fit-4cam", mmcsplat's own (not in ../shared/bench/README.md): what a first-frame fit
    of a real capture renders at its start, the workload of issue 27 — the Pose2Sim demo's four portrait
    1088×1920 cameras at a quarter of their size (272×480) around a standing person, and a few thousand
    Gaussians as the initializers place them (isotropic, opacity 0.1, sized by their spacing), each large
    enough to cover many 16-pixel tiles. Drawn in this order:

    - N = 3000; means = (rand(N, 3) · 2 − 1) · [0.25, 0.2, 0.85] + [0, 0, 0.9] (metres, z up);
    - quats = (1, 0, 0, 0); scales = exp(log(0.05) + 0.2 · randn(N, 1)) on all three axes;
    - opacities = 0.1; colours = rand(N, 3);
    - cameras at (3.5 cos θ, 3.5 sin θ, 1.0), θ = 45° + k · 90°, k = 0…3, looking at (0, 0, 0.9);
      f = 1675 · 272 / 1088 = 418.75, K = [[f, 0, 136], [0, f, 240], [0, 0, 1]].
    """
    n, width, height = 3000, 272, 480
    means = (torch.rand(n, 3, generator=g) * 2 - 1) * torch.tensor([0.25, 0.2, 0.85]) + torch.tensor([0.0, 0.0, 0.9])
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4).clone()
    scales = torch.exp(math.log(0.05) + 0.2 * torch.randn(n, 1, generator=g)).expand(n, 3).clone()
    opacities = torch.full((n,), 0.1)
    colors = torch.rand(n, 3, generator=g)
    angles = [math.radians(45 + 90 * k) for k in range(4)]
    viewmats = torch.stack([viewmat_looking_at((3.5 * math.cos(a), 3.5 * math.sin(a), 1.0), (0.0, 0.0, 0.9)) for a in angles])
    K = _intrinsics(1675 * width / 1088, width, height).expand(len(viewmats), 3, 3).clone()
    return BenchScene("D", SCENES["D"], Gaussians.from_linear(means, quats, scales, opacities, colors), RenderCameras(K, viewmats, width, height))


def leaves(scene: BenchScene) -> Gaussians:
    """Fresh copies of the scene's Gaussians; all but the (empty) features require grad. The gradients are
    those of the contract's parameters (log-scales, opacity logits): the README's linear scales and
    opacities differ from them by a fixed elementwise chain rule, the same for every backend."""
    return Gaussians(*(value.detach().clone().requires_grad_(field.name != "features")
                       for field, value in zip(attrs.fields(Gaussians), attrs.astuple(scene.gaussians, recurse=False))))


def step(renderer: Renderer, gaussians: Gaussians, cameras: RenderCameras) -> None:
    """One timed unit: forward, ``loss = (rgb ** 2).mean()``, gradients of every parameter."""
    loss = (renderer.render(gaussians, cameras).rgb ** 2).mean()
    g = gaussians
    torch.autograd.grad(loss, [g.means, g.quats, g.log_scales, g.opacity_logits, g.colors])


class PeakMemory:
    """Peak memory growth over a ``with`` block.

    Host: the kernel's resident-set high-water mark (VmHWM), reset through /proc/self/clear_refs, minus the
    RSS at entry (freed heap is first returned with malloc_trim so earlier runs do not hide growth); None
    where /proc does not offer it. CUDA: torch's peak allocation, when a CUDA device is in use.
    """

    def __init__(self) -> None:
        self.host_mib: float | None = None
        self.cuda_mib: float | None = None
        self._cuda_start = 0

    def __enter__(self) -> PeakMemory:
        release_freed_memory()
        self._start = _status_kib("VmRSS")
        try:
            Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current RSS
        except OSError:
            self._start = None
        if torch.cuda.is_available() and torch.cuda.is_initialized():
            torch.cuda.reset_peak_memory_stats()
            self._cuda_start = torch.cuda.memory_allocated()
        return self

    def __exit__(self, *exc: object) -> None:
        peak = _status_kib("VmHWM")
        if self._start is not None and peak is not None:
            self.host_mib = max(0, peak - self._start) / 1024
        if torch.cuda.is_available() and torch.cuda.is_initialized():
            self.cuda_mib = max(0, torch.cuda.max_memory_allocated() - self._cuda_start) / 2**20


def _status_kib(field: str) -> int | None:
    """A memory field of /proc/self/status in KiB (None off Linux)."""
    status = Path("/proc/self/status")
    match = re.search(rf"{field}:\s+(\d+)", status.read_text()) if status.exists() else None
    return int(match.group(1)) if match else None


@attrs.frozen
class Timing:
    """One backend on one scene: warm-up (first run, compilation included) and timed runs, in seconds;
    peak memory growth of the timed runs in MiB (None where not measurable)."""

    backend: str
    scene: str
    warmup_s: float
    runs_s: tuple[float, ...]
    peak_host_mib: float | None
    peak_cuda_mib: float | None

    @property
    def median_s(self) -> float:
        return statistics.median(self.runs_s)


@attrs.frozen
class SceneResult:
    """Every backend's timing on one scene, and each backend's speed-up over the baseline: the median of
    the per-run ratios baseline/backend (runs were interleaved, so each pair saw the same machine load)."""

    scene: str
    description: str
    timings: tuple[Timing, ...]
    speedups: Mapping[str, float]


@attrs.frozen
class BenchReport:
    """A whole ``mmcsplat bench`` run with its environment; ``profiles`` holds, for each missed target,
    the top of a cProfile of one run ("backend/scene" → text)."""

    results: tuple[SceneResult, ...]
    environment: Mapping[str, Any]
    repeats: int
    profiles: Mapping[str, str] = attrs.field(factory=dict)

    def missed_targets(self) -> list[tuple[str, str, float, float | None]]:
        """(backend, scene, target, measured speed-up or None) for every target not met in this run."""
        missed = []
        for result in self.results:
            for timing in result.timings:
                target = TARGETS.get((timing.backend, result.scene))
                measured = result.speedups.get(timing.backend)
                if target is not None and (measured is None or measured < target):
                    missed.append((timing.backend, result.scene, target, measured))
        return missed


def run_benchmark(
    scene_keys: Sequence[str],
    renderers: Mapping[str, Renderer],
    repeats: int = 7,
    progress: Callable[[str], None] | None = None,
    profile_missed: bool = True,
) -> BenchReport:
    """Time every renderer on every scene: one warm-up each, then ``repeats`` rounds in which the backends
    run one after the other, in an order rotated every round. With ``profile_missed``, each backend that
    misses its target is profiled over one more run, to explain the shortfall."""
    if repeats < 1:
        raise InputError(f"repeats must be at least 1, got {repeats}")
    names = sorted(renderers, key=lambda name: name != BASELINE)  # the baseline heads each table
    results = []
    for key in scene_keys:
        scene = build_scene(key)
        gaussians = {name: leaves(scene) for name in names}
        warmup = {}
        for name in names:
            if progress:
                progress(f"scene {key}: warm-up {name}")
            start = time.perf_counter()
            step(renderers[name], gaussians[name], scene.cameras)
            warmup[name] = time.perf_counter() - start
        runs: dict[str, list[float]] = {name: [] for name in names}
        peaks: dict[str, list[PeakMemory]] = {name: [] for name in names}
        for round_index in range(repeats):
            if progress:
                progress(f"scene {key}: round {round_index + 1}/{repeats}")
            for offset in range(len(names)):
                name = names[(round_index + offset) % len(names)]
                with PeakMemory() as peak:
                    start = time.perf_counter()
                    step(renderers[name], gaussians[name], scene.cameras)
                    runs[name].append(time.perf_counter() - start)
                peaks[name].append(peak)
        timings = tuple(
            Timing(name, key, warmup[name], tuple(runs[name]),
                   _max_or_none([p.host_mib for p in peaks[name]]), _max_or_none([p.cuda_mib for p in peaks[name]]))
            for name in names
        )
        speedups = {}
        if BASELINE in runs:
            for name in names:
                speedups[name] = statistics.median(b / t for b, t in zip(runs[BASELINE], runs[name]))
        results.append(SceneResult(key, scene.describe(), timings, speedups))
    report = BenchReport(tuple(results), environment(), repeats)
    if not profile_missed:
        return report
    profiles = {}
    for backend, scene_key, _, _ in report.missed_targets():
        if progress:
            progress(f"scene {scene_key}: profiling {backend}")
        profiles[f"{backend} on scene {scene_key}"] = profile_step(renderers[backend], scene_key)
    return attrs.evolve(report, profiles=profiles)


def _max_or_none(values: Sequence[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return max(known) if known else None


def profile_step(renderer: Renderer, scene_key: str, top: int = 15) -> str:
    """The ``top`` functions by cumulative time in one forward+backward run, as cProfile text."""
    scene = build_scene(scene_key)
    gaussians = leaves(scene)
    profiler = cProfile.Profile()
    profiler.runcall(step, renderer, gaussians, scene.cameras)
    out = io.StringIO()
    pstats.Stats(profiler, stream=out).strip_dirs().sort_stats("cumulative").print_stats(top)
    return out.getvalue().strip()


def environment() -> dict[str, Any]:
    """Machine, thread settings, versions and date of this run."""
    versions = {"python": platform.python_version()}
    for dist in VERSIONED:
        try:
            versions[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            pass
    threads: dict[str, Any] = {"torch": torch.get_num_threads(), "cpu_count": os.cpu_count()}
    if hasattr(os, "sched_getaffinity"):
        threads["usable_cpus"] = len(os.sched_getaffinity(0))
    if "numba" in sys.modules:
        threads["numba"] = sys.modules["numba"].config.NUMBA_NUM_THREADS
    threads.update({k: os.environ[k] for k in ("OMP_NUM_THREADS", "OMP_WAIT_POLICY", "NUMBA_NUM_THREADS", "NUMBA_THREADING_LAYER", "XLA_FLAGS") if k in os.environ})
    machine = {"platform": platform.platform(), "cpu": _cpu_model(), "memory_gib": round(_total_memory() / 2**30, 1)}
    if torch.cuda.is_available():
        machine["cuda_device"] = torch.cuda.get_device_name()
    return {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": machine,
        "threads": threads,
        "versions": versions,
    }


def _cpu_model() -> str:
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        match = re.search(r"model name\s*:\s*(.+)", cpuinfo.read_text())
        if match:
            return match.group(1).strip()
    return platform.processor() or "unknown"


def _total_memory() -> int:
    import psutil

    return psutil.virtual_memory().total


def to_markdown(report: BenchReport) -> str:
    """docs/performance.md: one table per scene, speed-ups against torch-reference, targets met or not,
    and the profile of every missed target."""
    env = report.environment
    threads = ", ".join(f"{k} {v}" for k, v in env["threads"].items())
    versions = ", ".join(f"{k} {v}" for k, v in env["versions"].items())
    lines = [
        "Written by `mmcsplat bench`. Forward + backward of `loss = (rgb ** 2).mean()` (black background) on",
        "the scenes of ../shared/bench/README.md, float32 on the CPU. Each backend first runs once (warm-up,",
        f"compilation included, reported apart); then {report.repeats} timed runs per backend, interleaved (the",
        "backends take turns, in an order rotated every round). Speed-up = median over rounds of",
        "(torch-reference time / backend time) in the same round. Peak memory = growth of the process's peak",
        "resident set (VmHWM) over one run, the largest over the timed runs.",
        "",
        f"- Date: {env['date']}",
        f"- Machine: {env['machine']['cpu']}, {env['machine']['memory_gib']} GiB, {env['machine']['platform']}"
        + (f", {env['machine']['cuda_device']}" if "cuda_device" in env["machine"] else ""),
        f"- Threads: {threads}",
        f"- Versions: {versions}",
        "",
    ]
    for result in report.results:
        lines += [f"### Scene {result.description}", "",
                  "| backend | warm-up (s) | median (s) | min–max (s) | peak memory (MiB) | speed-up | target |",
                  "|---|---|---|---|---|---|---|"]
        for t in result.timings:
            memory = "n/a" if t.peak_host_mib is None else f"{t.peak_host_mib:.0f}"
            if t.peak_cuda_mib is not None:
                memory += f" (CUDA {t.peak_cuda_mib:.0f})"
            speedup = result.speedups.get(t.backend)
            target = TARGETS.get((t.backend, result.scene))
            verdict = "" if target is None else (
                f"≥ {target:g}×: " + ("**met**" if speedup is not None and speedup >= target else "**not met**"))
            lines.append(f"| {t.backend} | {t.warmup_s:.3f} | {t.median_s:.3f} | {min(t.runs_s):.3f}–{max(t.runs_s):.3f} "
                         f"| {memory} | {'—' if speedup is None else f'{speedup:.2f}×'} | {verdict} |")
        lines.append("")
    missed = report.missed_targets()
    if missed:
        lines += ["## Targets not met", ""]
        for backend, scene, target, measured in missed:
            got = "not measured (torch-reference not in this run)" if measured is None else f"{measured:.2f}×"
            lines.append(f"- {backend} on scene {scene}: target ≥ {target:g}×, measured {got}.")
        for key, text in report.profiles.items():
            lines += ["", f"### Profile of one run: {key}", "", "```", text, "```"]
        lines.append("")
    return "\n".join(lines)


def to_json(report: BenchReport) -> dict[str, Any]:
    """The report as plain data, with each timing's median."""
    data = attrs.asdict(report, recurse=True)
    for result, result_data in zip(report.results, data["results"]):
        for timing, timing_data in zip(result.timings, result_data["timings"]):
            timing_data["median_s"] = timing.median_s
            timing_data["target_speedup"] = TARGETS.get((timing.backend, result.scene))
    data["missed_targets"] = [
        {"backend": b, "scene": s, "target": t, "speedup": m} for b, s, t, m in report.missed_targets()
    ]
    return data
