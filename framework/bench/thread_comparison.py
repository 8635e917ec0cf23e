"""The thread policy's controlled comparison (docs/performance.md, "Threads"): fit-like iterations on
bench scene D (torch-cpu render of one camera, L1 loss to a grey image, backward, Adam) with 2 threads,
1 thread and :class:`~mmcsplat.training.threads.ThreadPolicy`, each alone and beside one busy
``python -c "while True: pass"`` this script starts, in rounds whose order rotates so that a changing
ambient load falls on every condition alike.

    python -m mmcsplat.bench.thread_comparison [--iterations 40] [--rounds 3]

Prints one JSON line per run (seconds per iteration, the other processes' CPU use over the run, how
many iterations the policy ran on one thread) and, per condition, the median seconds per iteration and
the per-round ratios to 2 threads. It is a measurement harness, not part of a pipeline.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import time

import torch

from mmcsplat.bench.benchmark import build_scene, leaves
from mmcsplat.configuration.registry import default_registry
from mmcsplat.plugin_api.render_contract import RenderCameras
from mmcsplat.training.threads import ThreadPolicy, apply_threads, machine_cpus, others_cpus, read_cpu_times

MODES = ("2", "1", "policy")


def fit_iterations(mode: str, iterations: int, policy: ThreadPolicy) -> dict[str, float]:
    """``iterations`` fit-like steps with 2 or 1 fixed threads, or as ``policy`` chooses; seconds per
    iteration, the other processes' CPUs over the run and the iterations run on one thread."""
    scene = build_scene("D")
    renderer = default_registry().create("renderer", "torch-cpu")
    cameras = scene.cameras
    views = [RenderCameras(cameras.K[i:i + 1], cameras.viewmats[i:i + 1], cameras.width, cameras.height) for i in range(cameras.count)]
    target = torch.full((cameras.height, cameras.width, 3), 0.5)
    gaussians = leaves(scene)
    optimiser = torch.optim.Adam([gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits, gaussians.colors], lr=1e-3)
    apply_threads(policy.threads if mode == "policy" else int(mode))
    used = []
    before, start = read_cpu_times(), time.perf_counter()
    for i in range(iterations):
        used.append(policy.update() if mode == "policy" else int(mode))
        loss = (renderer.render(gaussians, views[i % len(views)]).rgb[0] - target).abs().mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    wall = time.perf_counter() - start
    after = read_cpu_times()
    others = others_cpus(before, after) if before is not None and after is not None else float("nan")
    return {"s_per_it": round(wall / iterations, 4), "others_cpus": round(others, 2), "iterations_at_1": used.count(1)}


def main(argv: list[str] | None = None) -> None:
    """Run the comparison and print its rows and summary."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--iterations", type=int, default=40, help="fit-like iterations per run")
    parser.add_argument("--rounds", type=int, default=3, help="rounds over the six conditions")
    args = parser.parse_args(argv)
    policy = ThreadPolicy(2, machine_cpus())  # one policy for the whole script, as a command keeps one
    fit_iterations("2", 2, policy)  # warm-up: numba compiles its kernels
    conditions = list(itertools.product(MODES, (False, True)))
    rows = []
    for round_ in range(args.rounds):
        shift = round_ % len(conditions)
        for mode, competing in conditions[shift:] + conditions[:shift]:
            competitor = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if competing else None
            try:
                if competitor is not None:
                    time.sleep(1.0)
                row = {"round": round_, "mode": mode, "competitor": competing, "loadavg1": os.getloadavg()[0],
                       **fit_iterations(mode, args.iterations, policy)}
            finally:
                if competitor is not None:
                    competitor.kill()
                    competitor.wait()
            rows.append(row)
            print(json.dumps(row), flush=True)
    for competing in (False, True):
        base = {row["round"]: row["s_per_it"] for row in rows if row["mode"] == "2" and row["competitor"] == competing}
        for mode in MODES:
            mine = [row for row in rows if row["mode"] == mode and row["competitor"] == competing]
            ratios = [round(row["s_per_it"] / base[row["round"]], 2) for row in mine]
            print(f"competitor={competing!s:5} threads={mode:6} median {statistics.median(r['s_per_it'] for r in mine):.4f} s/it, "
                  f"ratio to 2 threads per round {ratios}")


if __name__ == "__main__":
    main()
